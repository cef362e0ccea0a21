"""Would the gate withhold a wrong pose had the search also found the truth? (a measurement, README.md)

Registers pairs of the 3DMatch lists as ``regor-bench --threedmatch`` does (seed 0, viewpoints at
the origin, the normals facing the sensors unless ``off`` is given) with the benchmark's true pose
put first among the search's places, so that the gate refines it and weighs it like any rival.
Prints each pose's verdict and every rival's figures; TRUTH marks the refined truth.

    .venv/bin/python results/normals_current/truth_as_rival.py ../shared/data/threedmatch \
        3dmatch_studyroom_43_7,3dmatch_studyroom_65_24 [off]
"""
import sys
from pathlib import Path

from regor_ros.core import ORIGIN, RegorConfig, for_clouds_seen_from, prepare_cloud, register
from regor_ros.core.gate import measure
from regor_ros.core.metrics import rotation_error_deg, translation_error
from regor_ros.tools.threedmatch_benchmark import Fragments, as_pair, load_list

folder, names = Path(sys.argv[1]), sys.argv[2].split(",")
config = RegorConfig.preset("indoor")
if len(sys.argv) < 4 or sys.argv[3] != "off":
    config = config.replace({"features.normals_toward_sensors": True})
config = for_clouds_seen_from(config, ORIGIN, ORIGIN).replace({"seed": 0})
truth = {}
gate_rivals = measure.rivals


def rivals_with_truth(T, overlap, matches, places, *args, **kwargs):
    truth["figures"], truth["poses"] = gate_rivals(T, overlap, matches, [truth["T"], *places], *args, **kwargs)
    return truth["figures"], truth["poses"]


measure.rivals = rivals_with_truth
fragments = Fragments(folder)
for entry in (e for e in load_list(folder, None, None) if e["name"] in names):
    pair = as_pair(entry, fragments)
    truth.clear()
    truth["T"] = pair.T_gt
    result = register(prepare_cloud(pair.src, config, "source", viewpoint=ORIGIN),
                      prepare_cloud(pair.tgt, config, "target", viewpoint=ORIGIN), config)
    print(f"{entry['name']} {entry['bench']}: RE {rotation_error_deg(result.transform, pair.T_gt):.1f} "
          f"TE {translation_error(result.transform, pair.T_gt):.2f} published {result.accepted} {result.reason}")
    for row, pose in zip(truth["figures"].rows() if "figures" in truth else [], truth.get("poses", []), strict=True):
        off_deg, off_m = rotation_error_deg(pose, pair.T_gt), translation_error(pose, pair.T_gt)
        figures = " ".join(f"{name} {value:.3g}" if value is not None else f"{name} -" for name, value in row.items())
        print(f"    rival {off_deg:5.1f} deg {off_m:4.2f} m from the truth: {figures}"
              f"{' TRUTH' if off_deg < 5 and off_m < 0.3 else ''}")
