"""Held-out splits drawn from a private seed (``pipeline eval --test-seed``).

A held-out test slice (:data:`HELD_OUT_SLICES`) draws its episodes from its public seed,
so anyone can regenerate them. The same slice drawn from a secret instead keeps
everything else: the same generator, cells (motion type x speed x setting), episode
counts and order; only the draws differ, and nobody without the secret can regenerate
them.

The secret (a string of at least :data:`MIN_SECRET_CHARS` printable characters, at
least :data:`MIN_DISTINCT_CHARS` of them different; make one with
``python -c "import secrets; print(secrets.token_hex(16))"``) goes through scrypt (salt
``dyana/test-seed/v1/<slice>``, a fixed salt so the same secret gives the same bytes):
the first 8 bytes of the key give the generator seed (63 bits), the last 32 the hash a
run's manifest records (key ``test_seed``). Neither reveals the other, nor the secret.
The episodes' ``seed`` field is :data:`PRIVATE_SEED` (0, a value no public slice draws
from) and their ids keep the public form (``test-1k:000017``), so a run's files never
carry what regenerates the split.

The public recipe assigns test-1k's motions from held-out rows of public configuration
pools (:mod:`generators.grids`): a secret that only chose among them would hide an index,
not the motion. A private test-1k episode's motion is therefore drawn afresh
(:func:`private_motion`, scheme 2, recorded as ``test_seed.scheme``): every grid axis
uniform within half a grid step of the row the seed drew, so its values lie between the
grid's and no public row holds them. test-irregular and test-complex draw their motions
from the seed itself (:mod:`generators.appendix`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import hmac
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from schemas.errors import SpecError
from schemas.motion import ArcToken, HarmonicToken, LineToken, Motion
from schemas.names import printable
from schemas.slices import get_slice
from schemas.spec import EpisodeSpec

#: The slices a private seed may draw: their motion configurations are drawn, not assigned
#: (a training slice's configurations come from its table rows, whatever the seed).
HELD_OUT_SLICES = ("test-1k", "test-irregular", "test-complex")
MIN_SECRET_CHARS = 16
MIN_DISTINCT_CHARS = 8
MAX_SECRET_CHARS = 1024
#: The ``seed`` field of privately drawn episodes.
PRIVATE_SEED = 0
SALT_PREFIX = "dyana/test-seed/v1/"
#: scrypt's cost (N, r, p): 32 MiB and about a tenth of a second per derivation.
SCRYPT = {"n": 1 << 15, "r": 8, "p": 1}
HOW_TO_MAKE = 'make one with: python -c "import secrets; print(secrets.token_hex(16))"'
#: The manifest key of a privately drawn run.
MANIFEST_KEY = "test_seed"
#: Drawing schemes (the manifest's ``test_seed.scheme``; a record without one is 1): 1 took
#: test-1k's motions from public held-out pool rows (replayable, no longer drawn), 2 draws
#: them between the grid's values (:func:`private_motion`).
SCHEMES = {1: "public held-out rows", 2: "motions drawn off the grid"}
SCHEME = 2
#: The third word of a private motion's stream, ``SeedSequence([generator seed, episode index, PRIVATE_STREAM])``
#: (the recipe's streams have two).
PRIVATE_STREAM = 2
#: Draws of a private motion before the episode is infeasible.
PRIVATE_DRAWS = 64


def check_secret(secret: object) -> str:
    """``secret`` if it is strong enough; SpecError saying the rule (never the secret) otherwise."""
    if not isinstance(secret, str):
        raise SpecError(f"--test-seed must be a string, got {type(secret).__name__}")
    rule = (f"at least {MIN_SECRET_CHARS} printable characters without spaces, at least {MIN_DISTINCT_CHARS} "
            f"of them different")
    if len(secret) > MAX_SECRET_CHARS:
        raise SpecError(f"--test-seed is {len(secret):,} characters long (at most {MAX_SECRET_CHARS}); {HOW_TO_MAKE}")
    if not all(c.isprintable() and not c.isspace() for c in secret):
        raise SpecError(f"--test-seed holds a space or an unprintable character: use {rule}; {HOW_TO_MAKE}")
    if len(secret) < MIN_SECRET_CHARS or len(set(secret)) < MIN_DISTINCT_CHARS:
        raise SpecError(f"--test-seed is too weak ({len(secret)} characters, {len(set(secret))} different): use {rule}; "
                        f"{HOW_TO_MAKE}")
    return secret


@dataclass(frozen=True)
class TestSeed:
    """A private seed for one held-out slice: the generator seed (never printed) and the
    manifest record (:meth:`record`)."""

    __test__ = False  # not a pytest test class, whatever its name

    slice_name: str
    generator_seed: int = field(repr=False)
    digest: str
    #: How the episodes are drawn (:data:`SCHEMES`).
    scheme: int = SCHEME

    def __post_init__(self) -> None:
        if self.slice_name not in HELD_OUT_SLICES:
            raise SpecError(
                f"--test-seed draws the held-out test slices ({', '.join(HELD_OUT_SLICES)}), not {self.slice_name!r}: "
                "a training slice's motion configurations are assigned, not drawn, so a private seed would not hide them"
            )
        if isinstance(self.generator_seed, bool) or not isinstance(self.generator_seed, int) \
                or not 0 <= self.generator_seed < 1 << 63:
            raise SpecError("test seed: the generator seed must be an integer in [0, 2**63)")
        if self.scheme not in SCHEMES:
            raise SpecError(f"test seed: unknown drawing scheme {self.scheme!r} (this code draws {sorted(SCHEMES)})")

    def record(self) -> dict[str, Any]:
        """What a run's manifest keeps (key :data:`MANIFEST_KEY`): the KDF, its salt and the hash."""
        return {"kdf": "scrypt", **SCRYPT, "salt": SALT_PREFIX + self.slice_name, "hash": self.digest,
                "scheme": self.scheme}


def derive(secret: str, slice_name: str) -> TestSeed:
    """The private seed of ``slice_name`` from ``secret`` (checked first: :func:`check_secret`)."""
    check_secret(secret)
    get_slice(slice_name)
    salt = (SALT_PREFIX + slice_name).encode()
    key = hashlib.scrypt(secret.encode(), salt=salt, **SCRYPT, maxmem=64 << 20, dklen=64)
    return TestSeed(slice_name, int.from_bytes(key[:8], "big") >> 1, key[32:].hex())


def matching(secret: str, record: object, where: str) -> TestSeed:
    """The private seed ``secret`` gives, if it is the one ``record`` (a manifest's
    ``test_seed``) was made from; SpecError naming ``where`` otherwise."""
    if not isinstance(record, dict) or not isinstance(record.get("salt"), str) or not isinstance(record.get("hash"), str):
        raise SpecError(f"{where}: test_seed must be an object with salt and hash")
    expected = {"kdf": "scrypt", **SCRYPT}
    if {k: record.get(k) for k in expected} != expected or not record["salt"].startswith(SALT_PREFIX):
        raise SpecError(f"{where}: test_seed was made with another key derivation than this code's (scrypt {SCRYPT})")
    scheme = record.get("scheme", 1)  # runs made before the scheme was recorded drew public rows
    if isinstance(scheme, bool) or scheme not in SCHEMES:
        raise SpecError(f"{where}: test_seed was drawn by scheme {printable(scheme, 20)}, which this code does not know "
                        f"(it knows {sorted(SCHEMES)})")
    seed = derive(secret, record["salt"][len(SALT_PREFIX):])
    if not hmac.compare_digest(seed.digest, record["hash"]):
        raise SpecError(f"{where}: the test seed given does not match the one recorded (hash {record['hash'][:12]}...)")
    return dataclasses.replace(seed, scheme=scheme)


def motion_axes(token: Any) -> tuple[str, dict[str, float]]:
    """(motion type, grid axes) of a recipe token (the inverse of the recipe's token of a pool row)."""
    if isinstance(token, LineToken):
        return "linear", {"start_x": token.start[0], "start_z": token.start[1], "direction": token.direction,
                          "speed": token.speed, "relative_acceleration": token.acceleration / token.speed}
    if isinstance(token, ArcToken):
        return "circular", {"centre_x": token.centre[0], "centre_z": token.centre[1], "radius": token.radius,
                            "angular_velocity": token.angular_velocity, "start_angle": token.start_angle,
                            "turn": float(token.turn)}
    drift = -math.sin(token.axis) * token.drift[0] + math.cos(token.axis) * token.drift[1]
    return "harmonic", {"centre_x": token.centre[0], "centre_z": token.centre[1], "axis": token.axis,
                        "amplitude": token.amplitude, "frequency": token.frequency, "phase": token.phase, "drift": drift}


def _token(motion_type: str, cols: dict[str, np.ndarray], duration: float) -> Any:
    v = {name: float(values[0]) for name, values in cols.items()}
    if motion_type == "linear":
        return LineToken((v["start_x"], v["start_z"]), v["direction"], v["speed"], v["acceleration"], duration)
    if motion_type == "circular":
        return ArcToken((v["centre_x"], v["centre_z"]), v["radius"], v["angular_velocity"], v["start_angle"],
                        int(v["turn"]), duration)
    return HarmonicToken((v["centre_x"], v["centre_z"]), v["axis"], v["amplitude"], v["frequency"], v["phase"], duration,
                         (v["drift_x"], v["drift_z"]))


def _step(values: np.ndarray) -> float:
    return float(np.diff(np.unique(values)).min())


def private_motion(spec: EpisodeSpec, generator_seed: int) -> EpisodeSpec:
    """``spec`` with its motion drawn afresh: each grid axis (but a circle's turn) uniform
    within half a grid step of the drawn held-out row, rounded to 6 decimals, redrawn until
    feasible (:func:`generators.grids.feasible`, for the episode's object and duration).
    The values fall between the grid's, so no public pool row holds them."""
    from generators.grids import (
        GRID_AXES,
        OBJECT_NAMES,
        OBJECT_RADII,
        OBJECT_SIZES,
        OBJECT_TOPS,
        derived_columns,
        feasible,
    )

    token = spec.motion.base.tokens[0]
    motion_type, centre = motion_axes(token)
    obj = OBJECT_NAMES.index(spec.object)
    size = int(np.argmin(np.abs(OBJECT_SIZES[obj] - spec.object_size)))
    radius, top = OBJECT_RADII[obj : obj + 1, size], OBJECT_TOPS[obj : obj + 1, size]
    names = [name for name in GRID_AXES[motion_type] if name != "turn"]
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([generator_seed, spec.episode_index, PRIVATE_STREAM])))
    for attempt in range(PRIVATE_DRAWS):
        u = rng.random(len(names))
        scale = 1.0 - attempt / PRIVATE_DRAWS  # narrower each time: the row itself is feasible
        axes = {name: np.array([centre[name]]) for name in GRID_AXES[motion_type]}
        for name, draw in zip(names, u):
            axes[name] = np.round(axes[name] + (draw - 0.5) * scale * _step(GRID_AXES[motion_type][name]), 6) + 0.0
        cols = derived_columns(motion_type, axes)
        if feasible(motion_type, cols, np.array([token.duration]), radius, top)[0]:
            return dataclasses.replace(spec, motion=Motion.of(_token(motion_type, cols, token.duration)))
    raise SpecError(f"episode {spec.episode_index}: no feasible private motion in {PRIVATE_DRAWS} draws")


def private_specs(seed: TestSeed, first: int, end: int) -> list[EpisodeSpec]:
    """Episodes ``[first, end)`` of the slice, drawn from the private seed (module docstring):
    the recipe's episodes (test-1k) also get a privately drawn motion (:func:`private_motion`)."""
    from generators.recipe import definition_specs  # loaded only when drawing

    definition = dataclasses.replace(get_slice(seed.slice_name), seed=seed.generator_seed)
    specs = definition_specs(definition, first, end)
    if definition.generator == "recipe" and seed.scheme >= 2:
        specs = [private_motion(spec, seed.generator_seed) for spec in specs]
    return [dataclasses.replace(spec, seed=PRIVATE_SEED) for spec in specs]
