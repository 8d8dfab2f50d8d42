"""The plan of a cloud's reconstruction: settled from the cloud, printable, overridable, reproducible."""

import dataclasses

import numpy as np
import pytest

from voro3d.cli import PLAN_FIELDS, main
from voro3d.pointcloud import CloudPlan, cloud_mesh, reconstruct_points
from voro3d.pointcloud.plan import NORMALS, SWITCHES, TARGETS, as_plan
from voro3d.reconstruction import VoroMeshStage
from voro3d.sampling import sample_surface
from voro3d.shapes import example_mesh

FAST = dict(grid=16, steps=30)


@pytest.fixture(scope="module")
def torus():
    return sample_surface(example_mesh("torus"), 4000, seed=0)


def _arrays(mesh):
    return np.asarray(mesh.vertices), np.asarray(mesh.triangles)


def test_defaults_are_auto_and_print():
    plan = CloudPlan()
    assert all(getattr(plan, item.name) == "auto" for item in dataclasses.fields(plan))
    assert str(CloudPlan(target="imls", denoise="off")) == ("normals auto, denoise off, filter auto, target imls, hull auto, "
                                                            "thin auto")


@pytest.mark.parametrize("plan, error, match", [
    (dict(target="balls"), ValueError, r"plan target must be one of \('auto', 'poisson', 'imls', 'sheet'\), got 'balls'"),
    (dict(denoise=True), ValueError, "plan denoise must be one of"),
    (dict(smoothing="on"), ValueError, "plan has no field 'smoothing'"),
    ("imls", TypeError, "plan must be a CloudPlan, a dict of its fields or None, got str"),
])
def test_bad_plans_are_refused(plan, error, match):
    with pytest.raises(error, match=match):
        as_plan(plan)


def test_bad_plan_refused_before_any_work(torus):
    with pytest.raises(ValueError, match="plan filter must be one of"):
        VoroMeshStage(plan={"filter": "yes"})
    with pytest.raises(ValueError, match="plan normals 'check' needs normals"):
        reconstruct_points(torus[0], plan={"normals": "check"}, **FAST)


def test_the_plan_as_it_ran_gives_the_same_mesh(torus):
    points, normals = torus
    shape, target, info = reconstruct_points(points, normals, **FAST)
    assert info.plan == CloudPlan(normals="check", denoise="off", filter="off", target="poisson", hull="off", thin="off")
    again, target_again, info_again = reconstruct_points(points, normals, plan=info.plan, **FAST)
    assert info_again.plan == info.plan
    first, second = _arrays(cloud_mesh(shape, target)), _arrays(cloud_mesh(again, target_again))
    assert all(np.array_equal(a, b) for a, b in zip(first, second))


def test_each_choice_is_obeyed(torus):
    points, normals = torus
    forced = {"imls": "imls", "sheet": "sheet", "poisson": "poisson"}
    for choice, kind in forced.items():
        info = reconstruct_points(points, normals, plan={"target": choice}, **FAST)[2]
        assert info.target == kind and info.plan.target == kind
    assert reconstruct_points(points, normals, plan={"denoise": "on"}, **FAST)[2].smoothed
    # Inward normals: checked, they are flipped; trusted, they are kept (and read as an open scan).
    checked = reconstruct_points(points, -normals, **FAST)[2]
    assert checked.normals == "given, flipped" and checked.plan.target == "poisson"
    trusted = reconstruct_points(points, -normals, plan={"normals": "trust"}, **FAST)[2]
    assert trusted.normals == "given" and trusted.level == 0.0 and trusted.plan.target == "imls"
    estimated = reconstruct_points(points, -normals, plan={"normals": "estimate"}, **FAST)[2]
    assert estimated.normals == "estimated" and estimated.plan.normals == "estimate"


def test_cli_choices_are_the_plans():
    assert PLAN_FIELDS == {"normals": NORMALS, "denoise": SWITCHES, "filter": SWITCHES, "target": TARGETS, "hull": SWITCHES,
                           "thin": SWITCHES}


def test_cli_sets_and_prints_the_plan(tmp_path, torus, capsys):
    np.save(tmp_path / "cloud.npy", np.hstack(torus))
    assert main(["reconstruct", str(tmp_path / "cloud.npy"), "-o", str(tmp_path / "out.ply"), "--grid", "16",
                 "--steps", "20", "--target", "imls", "--denoise", "off", "--hull", "on"]) == 0
    err = capsys.readouterr().err
    assert "plan: normals check, denoise off, filter off, target imls, hull on, thin off" in err
    assert main(["reconstruct", str(tmp_path / "cloud.npy"), "-o", str(tmp_path / "x.ply"), "--normals", "check",
                 "--grid", "16"]) == 0  # the .npy holds normals
    np.save(tmp_path / "bare.npy", torus[0])
    assert main(["reconstruct", str(tmp_path / "bare.npy"), "-o", str(tmp_path / "y.ply"), "--normals", "trust"]) == 2
    assert "--normals 'trust' needs normals with the points; none were given" in capsys.readouterr().err
    assert not (tmp_path / "y.ply").exists()
