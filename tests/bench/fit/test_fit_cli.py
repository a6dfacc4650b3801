"""``arva-bench fit``: outputs, scene writing, the report, and exit status 2 with one
exact line for every kind of unusable input (BRIEF issue 6 item 4)."""

import json
import math
import tomllib

import numpy as np
import pytest

from bench.cli import main
from fit_campaign import emulate_campaign
from bench.fit.table import COLUMNS, Table
from emulator.receiver.model import ModelParams, measure
from emulator.scene.reader import load_scene


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    path = tmp_path_factory.mktemp("fit") / "walk.csv"
    emulate_campaign(20, ModelParams(kappa_eq=1.542, r_en=80.0), seed=5).write_csv(path)
    return path


def run(capsys, *argv):
    code = main(["fit", *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


def table_with(n=80, **changes) -> Table:
    t = emulate_campaign(0, ModelParams(), seed=1, n_rows=n)
    cols = t.columns()
    cols.update(changes)
    return Table.from_mapping("x", cols)


@pytest.mark.slow
def test_summary(campaign, capsys):
    code, out, err = run(capsys, campaign)
    assert code == 0 and err == ""
    lines = out.splitlines()
    assert lines[0] == f"fit: {campaign}: 1200 rows, 485 with d = -1"
    assert lines[1].startswith("kappa_eq    = 1.54") and lines[1].endswith("   (for transmitter moment s = 1)")
    assert lines[2].startswith("r_en        = ") and lines[2].endswith(" m")
    # exact poses: no GPS or attitude error is visible (both at their floors), so the
    # fit is that of exact poses (the inverse Hessian), and says so; its pose_sigma went
    # to its bound 1e-4, so it is held at 1e-5 and not printed as an estimate
    assert "; converged; " in lines[3]
    assert lines[5].startswith(
        "note: no pose error is visible (GPS and attitude error at their floors, 5 mm and 0.05 deg): fitted as exact "
        "poses (as --gps-sigma 0 --attitude-sigma 0; pose_sigma held at 1e-05, off its bound 0.0001, which smooths the "
        "noise edge; with the floors r_en was "
    )


def test_summary_with_exact_poses_given(campaign, capsys):
    """--gps-sigma 0 --attitude-sigma 0: the model without pose error, pose_sigma fitted."""
    code, out, err = run(capsys, campaign, "--gps-sigma", "0", "--attitude-sigma", "0", "--json")
    assert code == 0 and err == ""
    obj = json.loads(out)
    assert obj["free"] == ["kappa_eq", "r_en", "pose_sigma"] and obj["gps_sigma"] == 0.0
    assert abs(obj["kappa_eq"] / 1.542 - 1) < 0.01 and abs(obj["r_en"] / 80 - 1) < 0.05


@pytest.mark.parametrize(
    "argv, why",
    [
        (["--gps-sigma", "1,2,3"], "argument --gps-sigma: expected H or H,V (metres), got '1,2,3'"),
        (["--gps-sigma", "-1"], "argument --gps-sigma: must be >= 0, got -1"),
        (["--gps-sigma", "0,1"], "argument --gps-sigma: horizontal and vertical must both be 0 or both > 0, got '0,1'"),
        (["--attitude-sigma", "nan"], "argument --attitude-sigma: expected a finite number, got 'nan'"),
        (["--attitude-sigma", "200"], "argument --attitude-sigma: must be <= 180, got 200"),
        (["--gps-sigma", "1,abc"], "argument --gps-sigma: expected a number, got 'abc'"),
    ],
)
def test_pose_error_options_reject_bad_values(campaign, capsys, argv, why):
    with pytest.raises(SystemExit) as exc:
        main(["fit", str(campaign), *argv])
    out, err = capsys.readouterr()
    assert exc.value.code == 2 and out == "" and err.splitlines()[-1].endswith(why)


@pytest.mark.slow
def test_json_is_one_object_with_the_required_keys(campaign, capsys):
    code, out, err = run(capsys, campaign, "--json")
    assert code == 0 and err == "" and out.count("\n") == 1
    obj = json.loads(out)
    for key in ("kappa_eq", "kappa_eq_se", "r_en", "r_en_se", "n_rows", "n_censored", "log_likelihood"):
        assert isinstance(obj[key], (int, float)) and math.isfinite(obj[key]), key
    assert (obj["n_rows"], obj["n_censored"], obj["converged"]) == (1200, 485, True)
    assert abs(obj["kappa_eq"] / 1.542 - 1) < 0.01 and abs(obj["r_en"] / 80 - 1) < 0.05
    # exact poses: fitted as such (no pose error visible), the GPS error 0, pose_sigma
    # held at 1e-5 (fitted, it went to its bound 1e-4)
    assert obj["free"] == ["kappa_eq", "r_en"] and obj["separable"] is True and obj["pose_sigma"] == 1e-5
    assert obj["gps_sigma"] == 0.0 and obj["gps_sigma_vertical"] == 0.0


@pytest.mark.slow
def test_write_scene_creates_a_scene_the_emulator_loads(campaign, capsys, tmp_path):
    scene = tmp_path / "fitted.toml"
    code, out, err = run(capsys, campaign, "--json", "--write-scene", scene)
    assert code == 0 and err == f"arva-bench: fit: created {scene}\n"
    fitted = json.loads(out)
    s = load_scene(scene)
    assert s.model.kappa_eq == fitted["kappa_eq"] and s.model.r_en == fitted["r_en"]
    assert s.model.moment == 1.0 and s.effects.noise


@pytest.mark.slow
def test_write_scene_replaces_only_the_model_table(campaign, capsys, tmp_path):
    from importlib import resources

    original = resources.files("emulator").joinpath("scenes/field_walk.toml").read_text()
    scene = tmp_path / "field_walk.toml"
    scene.write_text(original.replace("[effects]", "[model]\nkappa_eq = 9.0\nr_en = 12.0\n\n[effects]"))
    code, _out, err = run(capsys, campaign, "--write-scene", scene)
    assert code == 0 and err == f"arva-bench: fit: updated {scene}\n"
    text = scene.read_text()
    assert "kappa_eq = 9.0" not in text and text.count("[model]") == 1
    before, after = original.split("[effects]")
    assert text.startswith(before) and text.endswith("[effects]" + after)
    model = tomllib.loads(text)["model"]
    assert set(model) == {"kappa_eq", "moment", "r_inner", "r_outer", "r_en", "q"}
    assert abs(model["kappa_eq"] / 1.542 - 1) < 0.01 and load_scene(scene).name == "field-walk"


@pytest.mark.slow
def test_write_scene_inserts_a_model_table(campaign, capsys, tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_text('spec = 1\n\n[[transmitters]]\nid = 1\nposition = [0.0, 0.0, 0.0]\n\n[receiver]\nchannels = 1\nposition = [5.0, 0.0, 0.0]\n')
    assert run(capsys, campaign, "--write-scene", scene)[0] == 0
    assert load_scene(scene).model.kappa_eq != 1.542 and scene.read_text().index("[model]") < scene.read_text().index("[[transmitters]]")


@pytest.mark.slow
def test_report_markdown(campaign, capsys, tmp_path):
    code, _out, err = run(capsys, campaign, "--report", tmp_path / "rep")
    assert code == 0 and err.startswith(f"arva-bench: fit: wrote {tmp_path / 'rep' / 'report.md'}")
    md = (tmp_path / "rep" / "report.md").read_text()
    assert md.startswith(f"# Receiver model fit: {campaign}\n")
    assert "| kappa_eq | 1.54" in md and "## Match per distance bin" in md and "Randomised PIT values" in md
    assert "| 78.0 - 81.0 | " in md  # the bins run to the farthest row


def test_report_diagnostics_of_a_correct_model(campaign):
    """On an emulated campaign the fitted model passes its own checks: randomised PIT
    values uniform (Kolmogorov 1 % critical value), 90 % bands holding ~90 % of the rows,
    observed and predicted -1 fractions equal within binomial error."""
    from bench.fit.csvio import read_csv
    from bench.fit.estimate import fit_table
    from bench.fit.report import diagnostics

    table = read_csv(campaign)
    diag = diagnostics(table, fit_table(table))
    assert diag.pit.shape == (1200,) and diag.ks < 1.63 / math.sqrt(1200)
    has = np.isfinite(diag.inside)
    inside = np.sum(diag.inside[has] * diag.n[has]) / np.sum(diag.n[has])
    assert abs(inside - 0.9) < 0.04
    n = diag.n[diag.n > 0]
    assert np.all(np.abs(diag.obs_cens - diag.model_cens)[diag.n > 0] < 4 * np.sqrt(0.25 / n) + 1e-9)
    assert np.mean(diag.d == -1) == pytest.approx(np.sum(diag.model_cens[diag.n > 0] * n) / n.sum(), abs=0.02)


@pytest.mark.slow
def test_report_figure(campaign, capsys, tmp_path):
    pytest.importorskip("matplotlib", reason="the report's PNG needs the plot extra (matplotlib)")
    assert run(capsys, campaign, "--report", tmp_path)[0] == 0
    png = (tmp_path / "fit.png").read_bytes()
    assert png.startswith(b"\x89PNG\r\n\x1a\n") and len(png) > 20_000
    assert "![d versus true distance](fit.png)" in (tmp_path / "report.md").read_text()


@pytest.mark.slow
def test_report_without_matplotlib(campaign, capsys, tmp_path, monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_matplotlib(name, *args, **kwargs):
        if name == "matplotlib" or name.startswith("matplotlib."):
            raise ImportError("no matplotlib")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_matplotlib)
    code, _out, err = run(capsys, campaign, "--report", tmp_path)
    assert code == 0 and not (tmp_path / "fit.png").exists() and (tmp_path / "report.md").exists()
    assert "arva-bench: fit: no figure: matplotlib is not installed (pip install 'arva-bench[plot]')" in err


def write(tmp_path, table: Table | str, name="in.csv"):
    path = tmp_path / name
    if isinstance(table, str):
        path.write_text(table)
    else:
        table.write_csv(path)
    return path


def bad_inputs(tmp_path):
    header = ",".join(COLUMNS) + "\n"
    walk = emulate_campaign(0, ModelParams(), seed=1, n_rows=80)
    static = table_with(rx_x=np.full(80, 20.0), rx_y=np.zeros(80), rx_z=np.zeros(80))
    far = table_with(rx_x=np.full(80, 200.0) + np.arange(80))
    far.d[:] = -1
    lines = walk.columns()
    big = table_with()
    big.d[7] = 5123
    return [
        (write(tmp_path, header, "empty.csv"), "{}: no data rows"),
        (write(tmp_path, walk.subset(np.arange(80) < 12), "few.csv"), "{}: only 12 rows; the fit needs at least 50"),
        (write(tmp_path, far, "far.csv"), "{}: all 80 rows are -1 (nothing was detected); walk closer to the transmitter"),
        (write(tmp_path, static, "static.csv"), "{}: no spread of distances: 90 % of rows lie between 20.02 and 20.02 m; walk over a range (at least a factor 1.25)"),
        (write(tmp_path, header + ",".join(["nan" if c == "rx_x" else str(lines[c][0]) for c in COLUMNS]) + "\n", "nan.csv"), "{}: line 2: column rx_x: not finite: 'nan'"),
        (write(tmp_path, ",".join(COLUMNS[:-1]) + "\n1\n", "cols.csv"), "{}: missing column tx_qz"),
        (write(tmp_path, big, "big.csv"), "{}: line 9: d = 5123 cm is beyond r_outer = 50 m; pass --r-outer or --fit r_outer"),
        (tmp_path / "nowhere.csv", "{}: cannot read: No such file or directory"),
    ]


def test_bad_inputs_exit_2_with_one_line(capsys, tmp_path):
    for path, reason in bad_inputs(tmp_path):
        code, out, err = run(capsys, path)
        assert (code, out) == (2, ""), path
        assert err == "arva-bench: fit: " + reason.format(path) + "\n"


def test_bad_arguments(campaign, capsys):
    assert run(capsys, campaign, "--fit", "q,foo") == (2, "", "arva-bench: fit: --fit: unknown parameter 'foo' (choose from q, r_outer, time_offset, height_offset, dropout, gps_outlier, mounting)\n")
    assert run(capsys, campaign, "--fit", "pose_sigma", "--pose-sigma", "0.01")[2] == (
        "arva-bench: fit: --fit pose_sigma and --pose-sigma contradict each other\n"
    )
    with pytest.raises(SystemExit) as exc:
        main(["fit", str(campaign), "--q", "1,2,1"])
    assert exc.value.code == 2
    assert "expected three numbers in (0, 1], got '1,2,1'" in capsys.readouterr().err


def test_no_convergence_exits_1_and_writes_no_scene(capsys, tmp_path):
    t = emulate_campaign(10, ModelParams(), seed=1)
    t.d = measure(t.rx_pos, t.rx_quat, t.tx_pos[:1], t.tx_quat[:1], ModelParams()).d[:, 0]  # no noise effect
    path = write(tmp_path, t)
    # exact poses: with the pose error free, r_en at its bound is "not determined" instead
    # (test_fit_identify.py)
    code, out, err = run(capsys, path, "--json", "--gps-sigma", "0", "--attitude-sigma", "0", "--write-scene", tmp_path / "s.toml")
    assert code == 1 and json.loads(out)["converged"] is False
    assert err == (
        "arva-bench: fit: did not converge: r_en runs to its upper bound 10000 (the data show no noise floor)\n"
        f"arva-bench: fit: not writing {tmp_path / 's.toml'}: no converged estimate\n"
    )
    assert not (tmp_path / "s.toml").exists()


@pytest.mark.slow
def test_stdin(campaign, capsys, monkeypatch):
    import io
    import sys

    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(campaign.read_bytes())))
    code, out, _ = run(capsys, "-", "--json")
    assert code == 0 and json.loads(out)["source"] == "<stdin>"


@pytest.mark.slow
def test_session_directory_goes_through_the_export(campaign, capsys, tmp_path, monkeypatch):
    from bench import export
    from bench.fit.csvio import read_csv

    code, out, err = run(capsys, tmp_path)
    assert code == 2 and err == f"arva-bench: fit: {tmp_path}: {tmp_path}: not a session directory (no manifest.json)\n"

    class Result:
        columns = read_csv(campaign).columns()

    monkeypatch.setattr(export, "export_rows", lambda directory: Result())
    code, out, err = run(capsys, tmp_path, "--json")
    assert code == 0 and json.loads(out)["n_rows"] == 1200 and json.loads(out)["source"] == str(tmp_path)
