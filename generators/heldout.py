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
"""

from __future__ import annotations

import dataclasses
import hashlib
import hmac
from dataclasses import dataclass, field
from typing import Any

from schemas.errors import SpecError
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

    def __post_init__(self) -> None:
        if self.slice_name not in HELD_OUT_SLICES:
            raise SpecError(
                f"--test-seed draws the held-out test slices ({', '.join(HELD_OUT_SLICES)}), not {self.slice_name!r}: "
                "a training slice's motion configurations are assigned, not drawn, so a private seed would not hide them"
            )
        if isinstance(self.generator_seed, bool) or not isinstance(self.generator_seed, int) \
                or not 0 <= self.generator_seed < 1 << 63:
            raise SpecError("test seed: the generator seed must be an integer in [0, 2**63)")

    def record(self) -> dict[str, Any]:
        """What a run's manifest keeps (key :data:`MANIFEST_KEY`): the KDF, its salt and the hash."""
        return {"kdf": "scrypt", **SCRYPT, "salt": SALT_PREFIX + self.slice_name, "hash": self.digest}


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
    seed = derive(secret, record["salt"][len(SALT_PREFIX):])
    if not hmac.compare_digest(seed.digest, record["hash"]):
        raise SpecError(f"{where}: the test seed given does not match the one recorded (hash {record['hash'][:12]}...)")
    return seed


def private_specs(seed: TestSeed, first: int, end: int) -> list[EpisodeSpec]:
    """Episodes ``[first, end)`` of the slice, drawn from the private seed (module docstring)."""
    from generators.recipe import definition_specs  # loaded only when drawing

    definition = dataclasses.replace(get_slice(seed.slice_name), seed=seed.generator_seed)
    return [dataclasses.replace(spec, seed=PRIVATE_SEED) for spec in definition_specs(definition, first, end)]
