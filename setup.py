"""Build of the one optional C extension; everything else is declared in pyproject.toml.

emulator.receiver.model_kernel is the batch model's fast path as one compiled loop
(emulator/receiver/model_kernel.c, docs/model.md). It is optional: without a C compiler
the build skips it and the numpy fast path runs. Plain C99 and CPython's buffer protocol,
so it needs no numpy headers. No -ffast-math and no FMA contraction: the kernel's
rounding must be the plain IEEE operations its margins were derived for.
"""

import sys

from setuptools import Extension, setup

FLAGS = [] if sys.platform == "win32" else ["-O3", "-std=c99", "-ffp-contract=off", "-fno-fast-math"]

setup(
    ext_modules=[
        Extension(
            "emulator.receiver.model_kernel",
            ["emulator/receiver/model_kernel.c"],
            extra_compile_args=FLAGS,
            optional=True,
        )
    ]
)
