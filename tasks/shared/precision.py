"""Which numeric path a network runs in on this CPU: bfloat16 where the CPU computes it fast, float32 elsewhere.

Shared by the networks of every system (DeepMoCap's two-stream FCN, the suit's code networks). torch answers the
CPU's features only through private helpers, so each answer has a stated default where torch gives none.
"""

from __future__ import annotations

import functools


@functools.lru_cache(maxsize=1)
def native_bfloat16() -> bool:
    """Whether this CPU computes bfloat16 natively (AVX512-BF16 or AMX); elsewhere torch emulates it, slower
    than float32. An unknown answer counts as native."""
    import torch

    try:
        return bool(torch.cpu._is_avx512_bf16_supported() or torch.cpu._is_amx_tile_supported())
    except AttributeError:
        return True


@functools.lru_cache(maxsize=1)
def amx_tiles() -> bool:
    """Whether this CPU has AMX tiles (an unknown answer counts as none)."""
    import torch

    try:
        return bool(torch.cpu._is_amx_tile_supported())
    except AttributeError:
        return False


def resolve_precision(precision: str) -> str:
    """The numeric path ``precision`` names on this CPU. "auto" is bfloat16 only with AMX tiles: measured per
    view-frame of the DeepMoCap network on one core, bfloat16 against float32 was 9.2 against 16.1 ms with AMX,
    25.4 against 20.6 ms with AVX512-BF16 alone and 129 against 31 ms with AVX2 alone (emulated); see
    docs/results.md. Any other value is kept, whatever the CPU."""
    if precision != "auto":
        return precision
    return "bfloat16" if amx_tiles() else "float32"
