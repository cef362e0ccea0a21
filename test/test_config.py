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


LENGTHS = ("features.voxel_size", "features.normal_radius", "features.fpfh_radius", "initial.inlier_threshold",
           "initial.compatibility_threshold", "initial.nms_radius", "initial.fs_tcd_threshold",
           "initial.refine_threshold", "regeneration.consistency_threshold", "regeneration.global_threshold",
           "estimation.inlier_threshold", "acceptance.free_space_margin")
# every preset's lengths in metres as they were set in metres, before they were set in voxels
IN_METRES = {"indoor": (0.05, 0.1, 0.25, 0.1, 0.1, 0.0, 0.05, 0.1, 0.1, 0.1, 0.1, 0.15),
             "outdoor": (0.3, 0.9, 1.5, 0.6, 0.1, 0.0, 0.1, 1.2, 0.1, 0.1, 1.2, 0.9),
             "object": (0.003, 0.006, 0.015, 0.006, 0.006, 0.0, 0.003, 0.006, 0.006, 0.006, 0.006, 0.009)}


@pytest.mark.parametrize("name", PRESETS)
def test_a_preset_set_in_voxels_gives_its_lengths_in_metres_to_the_bit(name):
    config = RegorConfig.preset(name)
    lengths = {"features.voxel_size": config.features.voxel_size, **config.lengths()}
    assert tuple(lengths[n] for n in LENGTHS) == IN_METRES[name]
    # and as its generated parameter file gives them (every digit written)
    from regor_ros.tools.write_presets import preset_yaml
    yaml = pytest.importorskip("yaml")
    written = yaml.safe_load(preset_yaml(name))["/**"]["ros__parameters"]
    flat = {f"{section}.{leaf}": value for section, values in written.items() if isinstance(values, dict)
            for leaf, value in values.items()}
    reread = RegorConfig.preset(name).replace({k: v for k, v in flat.items() if k in config.to_flat()})
    assert reread.lengths() == config.lengths()


def test_every_length_follows_the_voxel():
    """One knob for a new sensor: the voxel; the lengths that are no sensor's (a robot's height band,
    the verification's tolerance) stay."""
    indoor = RegorConfig.preset("indoor")
    coarser = indoor.replace({"voxel_size": 0.1})
    assert all(coarser.lengths()[n] == 2 * v for n, v in indoor.lengths().items())
    assert coarser.verification.max_correction == indoor.verification.max_correction
    assert coarser.gravity.height_tolerance == indoor.gravity.height_tolerance


def test_a_length_given_in_metres_sets_its_multiple_at_the_voxel_the_copy_ends_with():
    outdoor = RegorConfig.preset("outdoor")
    wider = outdoor.replace({"features.normal_radius": 1.2})
    assert wider.features.normal_radius_voxels == 4.0 and wider.features.normal_radius == 1.2
    finer = outdoor.replace({"features.normal_radius": 0.5, "voxel_size": 0.2})
    assert finer.features.normal_radius == 0.5 and finer.features.fpfh_radius == 1.0
    with pytest.raises(ConfigError, match="features.normal_radius_voxels"):
        outdoor.replace({"features.normal_radius": 0.1})   # under one voxel


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
