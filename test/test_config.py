import pytest

from regor_ros.core import ConfigError, RegorConfig
from regor_ros.core.config import PRESETS


@pytest.mark.parametrize("name", PRESETS)
def test_presets_are_valid(name):
    RegorConfig.preset(name).validate()


def test_outdoor_preset_uses_the_papers_kitti_settings():
    cfg = RegorConfig.preset("outdoor")
    assert cfg.features.voxel_size == 0.30
    assert cfg.initial.inlier_threshold == 0.6
    assert (cfg.initial.k1, cfg.initial.k2) == (40, 30)
    assert cfg.estimation.inlier_threshold == 1.2


def test_unknown_preset_names_the_choices():
    with pytest.raises(ConfigError, match="indoor, outdoor, object"):
        RegorConfig.preset("underwater")


def test_out_of_range_value_names_the_field():
    with pytest.raises(ConfigError, match="features.voxel_size"):
        RegorConfig().replace({"voxel_size": -1})


def test_stage_lists_must_match():
    with pytest.raises(ConfigError, match="one entry per stage"):
        RegorConfig().replace({"stage_seeds": [100]})


def test_k2_not_above_k1():
    with pytest.raises(ConfigError, match="initial.k2"):
        RegorConfig().replace({"initial.k2": 30})


def test_a_partial_visibility_check_needs_at_least_the_full_feature_support():
    with pytest.raises(ConfigError, match="min_feature_inliers_partial"):
        RegorConfig().replace({"min_feature_inliers_partial": 10})
    for name in ("indoor", "outdoor", "object"):
        gate = RegorConfig.preset(name).acceptance
        assert gate.min_feature_inliers_partial > gate.min_feature_inliers


def test_replace_accepts_dotted_and_unique_short_names_and_strings():
    cfg = RegorConfig().replace({"features.voxel_size": "0.04", "k1": "25",
                                 "dedupe_hypotheses": "false", "stage_neighbors": "50,10"})
    assert cfg.features.voxel_size == 0.04
    assert cfg.initial.k1 == 25
    assert cfg.initial.dedupe_hypotheses is False
    assert cfg.regeneration.stage_neighbors == [50, 10]
    assert RegorConfig().features.voxel_size == 0.05  # the original is untouched


def test_ambiguous_and_unknown_names_are_rejected():
    with pytest.raises(ConfigError, match="ambiguous"):
        RegorConfig().replace({"inlier_threshold": 0.2})
    with pytest.raises(ConfigError, match="unknown parameter"):
        RegorConfig().replace({"voxel": 0.2})


def test_subset_choice_is_checked():
    assert RegorConfig().replace({"subset": "random"}).initial.subset == "random"
    with pytest.raises(ConfigError, match="initial.subset"):
        RegorConfig().replace({"subset": "sometimes"})


def test_type_errors_are_reported_with_the_field():
    with pytest.raises(ConfigError, match="initial.k1"):
        RegorConfig().replace({"k1": "2.5"})


def test_every_field_has_a_description_and_range():
    for name, value, field in RegorConfig().parameters():
        assert field.metadata["description"], name
        if not isinstance(value, (bool, str)):
            low, high = field.metadata["range"]
            assert low is not None and high is not None, name


@pytest.mark.parametrize("name", PRESETS)
def test_committed_parameter_files_match_the_presets(name):
    from conftest import REPO

    from regor_ros.tools.write_presets import preset_yaml
    assert (REPO / "config" / f"{name}.yaml").read_text() == preset_yaml(name), \
        "run: python -m regor_ros.tools.write_presets config"


def test_node_reference_parameter_tables_are_current():
    from conftest import REPO

    from regor_ros.tools.write_presets import with_tables
    reference = (REPO / "doc" / "node.md").read_text()
    assert reference == with_tables(reference), "run: python -m regor_ros.tools.write_presets config doc/node.md"
    for name, _, _ in RegorConfig().parameters():
        assert f"`{name}`" in reference
