"""The motion-primitive registry: every token type has exactly one primitive."""

from __future__ import annotations

import subprocess
import sys

import pytest

from generators.primitives import Primitive, primitive_for, register, registered
from schemas.errors import SpecError
from schemas.motion import TOKEN_TYPES, LineToken


def test_every_token_type_has_one_registered_primitive() -> None:
    assert sorted(t.__name__ for t in registered()) == sorted(t.__name__ for t in TOKEN_TYPES.values())


def test_a_token_finds_its_primitive_and_a_non_token_is_refused() -> None:
    token = LineToken((0.0, 4.0), 0.3, 1.0, 0.0, 1.0)
    assert isinstance(primitive_for(token), Primitive)
    with pytest.raises(SpecError, match="not a motion token"):
        primitive_for("L")  # type: ignore[type-var]  # the wrong input is the point


def test_a_second_primitive_for_a_token_type_is_refused() -> None:
    with pytest.raises(ValueError, match="already registered"):

        @register(LineToken)
        class Again(Primitive[LineToken]):
            pass


def test_a_primitive_that_leaves_out_a_closed_form_cannot_be_registered() -> None:
    class NewToken:  # a token type no primitive handles yet
        pass

    with pytest.raises(TypeError, match="abstract"):

        @register(NewToken)  # type: ignore[arg-type]
        class Partial(Primitive):  # type: ignore[type-arg]
            def place(self, token, t0, prev):  # type: ignore[no-untyped-def]
                raise AssertionError("never called")

    assert NewToken not in registered()


def test_the_command_lines_start_without_scipy_special() -> None:
    """scipy.special (~0.7 CPU s to import) is loaded by the clothoid's Fresnel form only
    when a clothoid asks for it: a build, an evaluation or a score of the paper's
    slices, and each Dask worker, start without it; a clothoid still gets it."""
    code = (
        "import sys\n"
        "import pipeline.jobs.build, pipeline.jobs.evaluate, pipeline.cli_catalog, scoring.cli\n"
        "from generators.recipe import spec_for\n"
        "from generators.ground_truth import plan\n"
        "plan(spec_for('linear-fast', 0))\n"
        "assert 'scipy.special' not in sys.modules, 'scipy.special imported'\n"
        "import numpy as np\n"
        "from generators.primitives.clothoid import clothoid_integral\n"
        "clothoid_integral(0.0, 0.1, 0.02, np.linspace(0.0, 1.0, 5))\n"
        "assert 'scipy.special' in sys.modules\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
