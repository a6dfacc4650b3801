"""The receiver class as a sweep knob: the same seeded burials flown with a 2-antenna
and a 3-antenna receiver (SweepConfig.antennas, arva-sweep --antennas)."""

import pytest

from emulator.closed_loop.sweep import SweepConfig, burial, burial_scene, main, sweep

CONFIG = dict(n=2, seed=3, t_max=600.0, chunk=2, strategies=("flux", "receiver_only"))


def test_the_class_reaches_the_receiver_and_burials_stay_the_same():
    two, three = SweepConfig(antennas=2, **CONFIG), SweepConfig(**CONFIG)
    assert three.antennas == 3
    for i in range(2):
        assert burial(two, i) == burial(three, i)
        s2, _ = burial_scene(two, i, "flux", 1.0, 0.2)
        s3, _ = burial_scene(three, i, "flux", 1.0, 0.2)
        assert (s2.receiver_model().antennas, s3.receiver_model().antennas) == (2, 3)
        assert s2.seed == s3.seed


@pytest.mark.slow
@pytest.mark.parametrize(
    "antennas, flux_located, ro_error_median, ro_t_median",
    [(3, 0.5, 0.282308, 290.9), (2, 0.0, 0.898737, 283.75)],
)
def test_two_antennas_pinpoint_worse_on_the_same_burials(antennas, flux_located, ro_error_median, ro_t_median):
    r = sweep(SweepConfig(antennas=antennas, **CONFIG), workers=1)
    s = {row["strategy"]: row for row in r.summary}
    assert len(r.rows) == 12  # 2 strategies x 6 transmitters
    # Eq. 10 stops where the field turns vertical; a 2-antenna unit never sees h_z.
    assert s["flux"]["located"] == flux_located
    assert s["receiver_only"]["located"] == 1.0
    assert s["receiver_only"]["error_median_m"] == pytest.approx(ro_error_median, abs=1e-6)
    assert s["receiver_only"]["t_locate_median_s"] == pytest.approx(ro_t_median, abs=1e-9)


def test_command_line_option(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--antennas", "4", "--n", "1"])
    assert exc.value.code == 2
    assert "--antennas: invalid choice: 4 (choose from 2, 3)" in capsys.readouterr().err
