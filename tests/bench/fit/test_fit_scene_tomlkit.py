"""--write-scene on scenes as people write them (bench/fit/scene.py, through tomlkit):
comments and layout outside the model are kept byte for byte, and a model given as
dotted ``model.*`` keys or as an inline table is replaced by the fitted ``[model]``
table (before the first table), never left beside it."""

import tomllib

import numpy as np
import pytest

from bench.fit.params import Params
from bench.fit.result import FitResult
from bench.fit.scene import model_block, write_scene
from bench.fit.table import FitInputError
from emulator.scene.reader import load_scene

TAIL = """
# The buried transmitter, surveyed.
[[transmitters]]
id = 1     # the only one
position = [0.0, 0.0, -1.0]

[receiver]   # hand-held
position = [20.0, 0.0, 1.0]
"""


def fitted() -> FitResult:
    p = Params(kappa_eq=1.6, r_en=75.0, q=(1.0, 0.5, 1.0))
    return FitResult(source="walk.csv", params=p, free=("kappa_eq", "r_en"), estimate={"kappa_eq": 1.6, "r_en": 75.0},
                     se={"kappa_eq": 0.01, "r_en": 2.0}, cov_theta=np.zeros((2, 2)), log_likelihood=-1.0, n_rows=10,
                     n_censored=0, n_used=10, converged=True, message="", iterations=1, n_evals=1, seconds=0.0,
                     naive={}, exact_fraction=1.0)


@pytest.fixture
def block():
    return model_block(fitted())


def test_a_model_table_is_replaced_where_it_stands_and_every_comment_stays(tmp_path, block):
    head = "# My scene.\nspec = 1   # format\nseed = 7\n\n"
    scene = tmp_path / "s.toml"
    scene.write_text(head + "[model]  # old guess\nkappa_eq = 9.0  # far off\nr_en = 12.0\n\n# lead-in\n" + TAIL)
    assert write_scene(scene, fitted()) == "updated"
    assert scene.read_text() == head + block + "\n# lead-in\n" + TAIL
    assert load_scene(scene).model.kappa_eq == 1.6


@pytest.mark.parametrize(
    "head, kept",
    [
        ("spec = 1\nmodel.kappa_eq = 2.0  # a guess\nseed = 3\nmodel.r_en = 40.0\n", "spec = 1\nseed = 3\n\n"),
        ('spec = 1\nmodel = { kappa_eq = 2.0, r_en = 40.0 }  # inline\nname = "x"\n', 'spec = 1\nname = "x"\n\n'),
    ],
    ids=["dotted keys", "inline table"],
)
def test_a_dotted_or_inline_model_becomes_the_model_table(tmp_path, block, head, kept):
    scene = tmp_path / "s.toml"
    scene.write_text(head + TAIL)
    assert write_scene(scene, fitted()) == "updated"
    assert scene.read_text() == kept + block + TAIL
    assert tomllib.loads(scene.read_text())["model"] == tomllib.loads(block)["model"]
    assert load_scene(scene).model.r_en == 75.0


def test_a_scene_the_emulator_refuses_is_restored(tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_text("spec = 1  # nothing else\n")
    with pytest.raises(FitInputError, match="the scene would not load"):
        write_scene(scene, fitted())  # no transmitter: the emulator refuses it, the file is restored
    assert scene.read_text() == "spec = 1  # nothing else\n"


def test_not_toml_is_one_error_and_the_file_is_kept(tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_text("spec = = 1\n")
    with pytest.raises(FitInputError, match=rf"^fit: {scene}: the scene would not load: Unexpected character: .=. at line 1 col 7$"):
        write_scene(scene, fitted())
    assert scene.read_text() == "spec = = 1\n"
