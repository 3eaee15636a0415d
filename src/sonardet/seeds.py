"""Seeds and provenance hashes: the leaf module every layer may import (it imports nothing of sonardet).

Every stochastic step draws its seed from the config seed and the step's keys (:func:`derive_seed`), so
the same config gives the same bytes in any process and on any Python version; outputs record the
hash of the config section that made them (:func:`config_hash`).
"""

from __future__ import annotations

import hashlib
import json

__all__ = ["config_hash", "derive_seed"]


def config_hash(section) -> str:
    """Short stable hash (hex, 12 chars) of a config section, for provenance in outputs."""
    blob = json.dumps(section, sort_keys=True, separators=(",", ":")).encode()
    return hashlib.sha256(blob).hexdigest()[:12]


def derive_seed(base_seed: int, *keys) -> int:
    """Seed for one stochastic step, derived from the config seed and the step's keys (e.g. stage
    name and scene id). Stable across Python versions and processes (no use of hash())."""
    blob = json.dumps([int(base_seed), *map(str, keys)]).encode()
    return int.from_bytes(hashlib.blake2b(blob, digest_size=8).digest(), "little") >> 1
