"""The pair list of a batch: one candidate pair per row, in CSV (with a header) or JSON lines.

Columns: ``source`` and ``target`` (cloud files, relative to the scans folder when one is given,
else to the list's own folder), optional ``id`` (default: the row's line number; give ids when the
list may be edited between a run and its resumption), ``source_viewpoint`` / ``target_viewpoint``
('x, y, z', 'none' for a map or an aggregated cloud, default the cloud's origin), ``preset`` and
``pose``: the candidate's T_target_source (16 numbers, the 4x4 row by row, or 7: x y z qx qy qz qw;
a SLAM back end's loop closure), which the row then verifies instead of registering.
A row that cannot run (an empty path, a bad viewpoint, an unknown preset) is kept with the reason,
so that it gets an error row in the output; a list that cannot be read at all raises ListError.
"""
from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core import PRESETS, ConfigError, RegistrationError, parse_viewpoint
from .verify_cli import pose_from_numbers

COLUMNS = ("id", "source", "target", "source_viewpoint", "target_viewpoint", "preset", "pose")


class ListError(Exception):
    """A pair list that cannot be used at all (no file, no source/target columns, repeated ids)."""


@dataclass(frozen=True)
class PairRow:
    id: str
    source: str                  # as written in the list
    target: str
    source_path: Path | None  # resolved; None when the row has an error
    target_path: Path | None
    source_viewpoint: object     # a parse_viewpoint result: (x, y, z), or None for unknown
    target_viewpoint: object
    preset: str
    error: str = ""              # why the row cannot run; empty when it can
    pose: tuple[float, ...] | None = None  # the 4x4 to verify, row by row; None: register the pair

    def clouds(self):
        """The (path, viewpoint) of each cloud: what identifies a prepared cloud."""
        return (self.source_path, self.source_viewpoint), (self.target_path, self.target_viewpoint)


def _viewpoint_text(value) -> str:
    """A viewpoint cell as parse_viewpoint reads it; JSON may also give a list or null."""
    if value is None:
        return "none"
    if isinstance(value, (list, tuple)):
        return ", ".join(str(v) for v in value)
    return str(value).strip() or "auto"


def _row(fields: dict[str, object], line: int, folder: Path, default_preset: str) -> PairRow:
    text = {k: ("" if fields.get(k) is None else str(fields.get(k)).strip())
            for k in ("id", "source", "target", "preset", "pose")}
    row_id = text["id"] or str(line)
    source, target = text["source"], text["target"]
    preset = text["preset"] or default_preset
    try:
        if "error" in fields:  # a JSON line that could not be read
            raise ConfigError(fields["error"])
        if not source or not target:
            raise ConfigError("the row needs both a source and a target file")
        if preset not in PRESETS:
            raise ConfigError(f"preset {preset!r} is not one of {', '.join(PRESETS)}")
        viewpoints = [parse_viewpoint(_viewpoint_text(fields.get(f"{side}_viewpoint", "auto")), f"{side}_viewpoint")
                      for side in ("source", "target")]
        pose = _pose(fields.get("pose"), text["pose"])
    except (ConfigError, RegistrationError) as exc:
        return PairRow(row_id, source, target, None, None, None, None, preset, str(exc))
    return PairRow(row_id, source, target, folder / source, folder / target, viewpoints[0], viewpoints[1], preset,
                   pose=pose)


def _pose(value, text: str) -> tuple[float, ...] | None:
    """The row's pose cell (numbers separated by spaces or commas; JSON may also give a list, or a
    4x4 list of rows) as the 16 numbers of its 4x4, or None when empty."""
    if value is None or not text:
        return None
    if isinstance(value, (list, tuple)):
        numbers = np.asarray(value, dtype=np.float64).ravel()
    else:
        try:
            numbers = np.array([float(v) for v in text.replace(",", " ").split()])
        except ValueError:
            raise ConfigError(f"pose {text!r}: not numbers") from None
    return tuple(pose_from_numbers(numbers, "pose").ravel().tolist())


def _json_lines(path: Path):
    """(line number, fields) of each non-empty line; a line that is not a JSON object gives
    fields with an ``error``."""
    with open(path, encoding="utf-8") as f:
        for line, text in enumerate(f, 1):
            if not text.strip():
                continue
            try:
                fields = json.loads(text)
            except json.JSONDecodeError as exc:
                fields = {"error": f"line {line} is not JSON ({exc.msg})"}
            if not isinstance(fields, dict):
                fields = {"error": f"line {line} is not a JSON object"}
            yield line, fields


def _csv_rows(path: Path):
    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        missing = {"source", "target"} - set(reader.fieldnames or ())
        if missing:
            raise ListError(f"{path}: the header must name the columns source and target "
                            f"(optional: {', '.join(c for c in COLUMNS if c not in ('source', 'target'))}); "
                            f"it has {', '.join(reader.fieldnames or ['nothing'])}")
        for fields in reader:  # a short row's missing cells are empty, as written
            yield reader.line_num, {k: "" if v is None else v for k, v in fields.items()}


def read_pairs(path, scans=None, default_preset: str = "indoor") -> list[PairRow]:
    """The rows of a pair list (``.csv``, or JSON lines for any other name)."""
    path = Path(path).expanduser()
    if not path.is_file():
        raise ListError(f"{path}: no such pair list")
    folder = Path(scans).expanduser() if scans else path.parent
    if scans and not folder.is_dir():
        raise ListError(f"{folder}: no such scans folder")
    lines = _csv_rows(path) if path.suffix.lower() == ".csv" else _json_lines(path)
    rows: list = []
    seen: dict = {}
    try:
        for line, fields in lines:
            row = _row(fields, line, folder, default_preset)
            if row.id in seen:
                raise ListError(f"{path}: id {row.id!r} is on lines {seen[row.id]} and {line}; ids must be unique")
            seen[row.id] = line
            rows.append(row)
    except (UnicodeDecodeError, csv.Error) as exc:
        raise ListError(f"{path}: not a CSV or JSON-lines text file ({exc})") from None
    if not rows:
        raise ListError(f"{path}: no pairs in the list")
    return rows
