"""Receiver profiles (emulator/receiver/profiles/*.toml) and the scene keys
``[receiver] antennas`` / ``profile``: loading, strict validation, merge order, bytes."""

import numpy as np
import pytest
import repo_paths

from emulator.cli import main as emulate_main
from emulator.receiver.model import ModelParams
from emulator.receiver.profile import (
    PROFILE_FORMAT,
    load_profile,
    load_profile_file,
    parse_profile,
    profile_names,
    profile_table,
)
from emulator.receiver.quantize import QuantizeConfig
from emulator.receiver.receiver import Receiver
from emulator.scene.reader import default_scene, loads_scene
from firmware_proto.errors import InputError, SceneError
from firmware_proto.sentences import encode_epoch

SHIPPED = ["digital2", "digital3_leds5", "paper"]
EXPECTED_LEDS5 = b"$PARVA,0,3,1,4,1400,-36*7F\r\n$PARVA,0,3,2,-1,-1,-1*79\r\n$PARVA,0,3,3,-1,-1,-1*78\r\n"
VERTICAL = "[0.7071067811865476, 0.0, -0.7071067811865476, 0.0]"


def scene(receiver: str, top: str = "", tables: str = "", depth: float = 2.0):
    """A vertical transmitter ``depth`` m below the origin and one receiver."""
    text = f"""spec = 1
{top}
[[transmitters]]
id = 1
position = [0.0, 0.0, {-depth}]
orientation = {VERTICAL}
[receiver]
position = [0.0, 0.0, 0.0]
{receiver}
{tables}"""
    return loads_scene(text, "s.toml")


def readings(s, xs):
    """(d, delta) of the first slot with the receiver moved to (x, 0, 0) for each x."""
    rx = Receiver(s)
    pos = np.array([[x, 0.0, 0.0] for x in xs])
    ep = rx.evaluate_poses(np.zeros(len(xs)), pos, np.tile([1.0, 0.0, 0.0, 0.0], (len(xs), 1)))
    return list(zip(ep.d[:, 0].tolist(), ep.delta[:, 0].tolist()))


class TestShippedProfiles:
    def test_names_and_contents(self):
        assert profile_names() == SHIPPED
        p = load_profile("digital2")
        assert (p.version, p.antennas, p.channels, p.rate_hz) == (1, 2, 1, 1.0)
        assert p.model == ModelParams(r_outer=40.0, antennas=2)
        assert p.display == QuantizeConfig(profile="display_dm")
        q = load_profile("digital3_leds5")
        assert (q.antennas, q.channels) == (3, 3)
        assert q.display == QuantizeConfig(delta_step_deg=36, d_step_cm=10, d_far_cm=1000, d_step_far_cm=100)
        paper = load_profile("paper")
        assert paper.model == ModelParams() and paper.display is None and paper.channels == 1

    def test_every_file_has_a_comment_saying_what_it_stands_for(self):
        from importlib import resources

        for name in SHIPPED:
            text = (resources.files("emulator.receiver") / "profiles" / f"{name}.toml").read_text()
            assert text.startswith("# "), name
            assert f'name = "{name}"' in text and f"format = {PROFILE_FORMAT}" in text

    def test_unknown_profile(self):
        with pytest.raises(InputError, match=r"^unknown receiver profile 'x' \(known: digital2, digital3_leds5, paper\)$"):
            load_profile("x")

    def test_list_profiles_command(self, capsys):
        assert emulate_main(["--list-profiles"]) == 0
        out = capsys.readouterr().out
        assert out == profile_table()
        lines = out.splitlines()
        assert lines[0].split() == ["NAME", "VERSION", "ANTENNAS", "DESCRIPTION"]
        assert [ln.split()[:3] for ln in lines[1:]] == [["digital2", "1", "2"], ["digital3_leds5", "1", "3"], ["paper", "1", "3"]]


GOOD = {
    "format": 1, "name": "t", "version": 2, "description": "a test unit", "antennas": 2, "channels": 2,
    "rate_hz": 2.0, "model": {"r_outer": 30.0}, "display": {"profile": "leds3"},
}  # fmt: skip


class TestValidation:
    def test_good(self):
        p = parse_profile(GOOD, "t.toml", "t")
        assert (p.name, p.version, p.channels, p.rate_hz) == ("t", 2, 2, 2.0)
        assert p.model == ModelParams(r_outer=30.0, antennas=2)
        assert p.display.delta_step_deg == 60

    @pytest.mark.parametrize(
        "change, message",
        [
            ({"colour": "red"}, "t.toml: colour: unknown key"),
            ({"model": {"moment": 2.0}}, "t.toml: model.moment: unknown key"),
            ({"model": {"r_outer": -1}}, "t.toml: model.r_outer: must be >= 1e-06, got -1"),
            ({"model": {"q": [1.0, 0.0, 1.0]}}, "t.toml: model.q[1]: must be >= 1e-06, got 0"),
            ({"model": 3}, "t.toml: model: expected a table, got an integer"),
            ({"display": {"leds": 5}}, "t.toml: display.leds: unknown key"),
            ({"display": {"profile": "nixie"}}, "t.toml: display: quantize.profile: must be one of leds5, leds3, display_dm, display_m, got 'nixie'"),
            ({"format": 2}, "t.toml: format: version 2 is newer than this program supports (1)"),
            ({"name": "u"}, "t.toml: name: must equal the file name 't', got 'u'"),
            ({"antennas": 1}, "t.toml: antennas: must be in 2..3, got 1"),
            ({"antennas": True}, "t.toml: antennas: expected an integer, got a boolean"),
            ({"channels": 0}, "t.toml: channels: must be in 1..99, got 0"),
            ({"rate_hz": 1e6}, "t.toml: rate_hz: must be within [0.001, 10000] Hz, got 1e+06"),
            ({"description": ""}, "t.toml: description: expected one non-empty line, got ''"),
            ({"version": 0}, "t.toml: version: must be in 1..2147483648, got 0"),
        ],
    )
    def test_errors_name_file_and_key(self, change, message):
        with pytest.raises(SceneError) as exc:
            parse_profile({**GOOD, **change}, "t.toml", "t")
        assert str(exc.value) == message

    @pytest.mark.parametrize("key", ["format", "description", "antennas", "channels", "rate_hz"])
    def test_missing_keys(self, key):
        data = {k: v for k, v in GOOD.items() if k != key}
        with pytest.raises(SceneError, match=rf"^t.toml: {key}: missing"):
            parse_profile(data, "t.toml", "t")

    def test_file_errors(self, tmp_path):
        f = tmp_path / "mine.toml"
        f.write_text('format = 1\nname = "mine"\nversion = 1\ndescription = "x"\nantennas = 3\nchannels = 1\nrate_hz = 1.0\n')
        assert load_profile_file(f).name == "mine"
        f.write_text("format = [")
        with pytest.raises(SceneError, match=rf"^{f}: TOML syntax: "):
            load_profile_file(f)


class TestSceneKeys:
    def test_no_profile_is_todays_receiver(self):
        s = scene("")
        assert s.receiver_model() == ModelParams() and s.receiver.profile == "" and s.receiver.display is None

    def test_antennas_key(self):
        s = scene("antennas = 2")
        assert s.receiver_model().antennas == 2
        # Above the vertical transmitter: the 2-antenna spike; half the depth off: its maximum.
        assert readings(s, [0.0, 1.0]) == [(-1, -1), (243, 0)]
        assert readings(scene("antennas = 3"), [0.0, 1.0]) == [(183, 0), (211, 0)]

    def test_profile_sets_class_channels_model_display(self):
        s = scene('profile = "digital2"')
        rx = s.receiver
        assert (rx.profile, rx.channels, s.rate_hz) == ("digital2", 1, 1.0)
        assert s.receiver_model() == ModelParams(r_outer=40.0, antennas=2)
        # display_dm: 243 cm shows as 240, 436 as 440.
        assert readings(s, [0.0, 1.0, 0.1]) == [(-1, -1), (240, 0), (440, 0)]

    def test_scene_keys_override_the_profile(self):
        s = scene('profile = "digital2"\nchannels = 3\nantennas = 3', top="rate_hz = 2.0",
                  tables="[model]\nr_outer = 45.0\nkappa_eq = 1.5\n")  # fmt: skip
        assert (s.receiver.channels, s.rate_hz) == (3, 2.0)
        assert s.receiver_model() == ModelParams(kappa_eq=1.5, r_outer=45.0, antennas=3)
        assert s.model == s.receiver_model(0)  # the first receiver's

    def test_scene_quantize_overrides_the_profile_display(self):
        off = scene('profile = "digital2"', tables="[effects]\nquantize = false\n")
        assert readings(off, [1.0]) == [(243, 0)]
        leds = scene('profile = "digital2"', tables='[effects]\nquantize = true\n[quantize]\nprofile = "display_m"\n')
        assert readings(leds, [1.0]) == [(200, 0)]

    def test_leds5_profile_exact_sentence(self):
        s = loads_scene(
            'spec = 1\n[[transmitters]]\nid = 4\nposition = [0.0, 12.0, 0.0]\n'
            '[receiver]\nprofile = "digital3_leds5"\nposition = [0.0, 0.0, 0.0]\n'
            'orientation = [0.9659258262890683, 0.0, 0.0, 0.25881904510234154]\n',  # yaw 30 deg
            "s.toml",
        )
        ep = Receiver(s).evaluate(np.array([0.0]))
        # Exact: dxy = 12 cbrt(1.542) / cbrt(1) = 13.86 m -> 1386 -> 1400 (1 m steps beyond 10 m);
        # delta = -30 -> LED -36. Three channels, two empty.
        slots = list(zip(ep.ids[0].tolist(), ep.d[0].tolist(), ep.delta[0].tolist()))
        assert encode_epoch(0, slots) == EXPECTED_LEDS5

    def test_paper_profile_reproduces_the_default_scene(self):
        base = default_scene()
        text = (
            "spec = 1\n"
            + "".join(f"[[transmitters]]\nid = {tx.id}\nposition = {tx.trajectory.positions[0].tolist()}\n" for tx in base.transmitters)
            + '[receiver]\nprofile = "paper"\nchannels = 4\nposition = [0.0, 0.0, 0.0]\n'
        )
        s = loads_scene(text, "p.toml")
        t = np.arange(3.0)
        a, b = Receiver(base).evaluate(t), Receiver(s).evaluate(t)
        assert a.d.tolist() == b.d.tolist() and a.delta.tolist() == b.delta.tolist() and a.ids.tolist() == b.ids.tolist()

    @pytest.mark.parametrize(
        "receiver, top, message",
        [
            ('profile = "nope"', "", "s.toml: receiver.profile: unknown receiver profile 'nope' (known: digital2, digital3_leds5, paper)"),
            ("profile = 2", "", "s.toml: receiver.profile: expected a string, got an integer"),
            ("antennas = 4", "", "s.toml: receiver.antennas: must be in 2..3, got 4"),
            ("antennas = 2.0", "", "s.toml: receiver.antennas: expected an integer, got a number"),
        ],
    )
    def test_scene_errors(self, receiver, top, message):
        with pytest.raises(SceneError) as exc:
            scene(receiver, top)
        assert str(exc.value) == message

    def test_profiles_with_different_rates_need_a_scene_rate(self, tmp_path, monkeypatch):
        import emulator.receiver.profile as prof

        fast = parse_profile({**GOOD, "name": "fast"}, "fast.toml", "fast")  # 2 Hz
        real = prof.load_profile
        monkeypatch.setattr("emulator.scene.reader.load_profile", lambda n: fast if n == "fast" else real(n))
        two = (
            'spec = 1\n{top}\n[[receivers]]\nprofile = "fast"\nposition = [0.0, 0.0, 0.0]\n'
            '[[receivers]]\nprofile = "paper"\nposition = [1.0, 0.0, 0.0]\n'
        )
        with pytest.raises(SceneError) as exc:
            loads_scene(two.format(top=""), "s.toml")
        assert str(exc.value) == (
            "s.toml: rate_hz: missing: the receivers' profiles differ in epoch rate (fast 2 Hz, paper 1 Hz); set rate_hz"
        )
        s = loads_scene(two.format(top="rate_hz = 4.0"), "s.toml")
        assert s.rate_hz == 4.0
        assert [s.receiver_model(i).antennas for i in range(2)] == [2, 3] and s.model.antennas == 2
        assert [rx.channels for rx in s.receivers] == [2, 1]


def test_shipped_two_antenna_spike_scene():
    from emulator.scene.reader import load_scene
    
    s = load_scene(repo_paths.SCENES / "two_antenna_spike.toml")
    two, three = (Receiver(s, i).next_batch(13).epochs for i in (0, 1))
    # x = -1.5 .. 1.5 m in 0.25 m steps over a vertical transmitter 2 m deep.
    assert two.d[:, 0].tolist() == [260, 250, 240, 250, 270, 330, -1, 330, 270, 250, 240, 250, 260]  # 0.1 m display
    assert three.d[:, 0].tolist() == [242, 225, 211, 199, 190, 185, 183, 185, 190, 199, 211, 225, 242]
    assert two.delta[6, 0] == -1 and two.ids[6, 0] == -1  # the spike: no signal above the victim


from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

_values = st.recursive(
    st.none().map(lambda _: 0) | st.booleans() | st.integers(-5, 200) | st.floats(allow_nan=True) | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.sampled_from(["q", "r_outer", "profile", "x", "delta_step_deg"]), inner, max_size=3),
    max_leaves=8,
)
_keys = st.sampled_from(sorted(GOOD) + ["moment", "extra"])


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(changes=st.dictionaries(_keys, _values, max_size=4), drop=st.sets(st.sampled_from(sorted(GOOD)), max_size=2))
def test_any_document_is_a_profile_or_one_scene_error(changes, drop):
    data = {k: v for k, v in {**GOOD, **changes}.items() if k not in drop}
    try:
        p = parse_profile(data, "t.toml", "t")
    except SceneError as exc:
        text = str(exc)
        assert text.startswith("t.toml: ") and "\n" not in text
        return
    assert p.antennas in (2, 3) and 1 <= p.channels <= 99 and p.rate_hz > 0
