"""The numeric path a network runs in: "auto" is bfloat16 only with AMX tiles; a named precision is kept."""

from __future__ import annotations

from mocapflow.tasks.shared import precision


def test_auto_precision_is_bfloat16_only_with_amx(monkeypatch):
    monkeypatch.setattr(precision, "amx_tiles", lambda: True)
    assert precision.resolve_precision("auto") == "bfloat16"
    monkeypatch.setattr(precision, "amx_tiles", lambda: False)
    assert precision.resolve_precision("auto") == "float32"
    assert precision.resolve_precision("bfloat16") == "bfloat16"  # asked for: kept, whatever the CPU
    assert precision.resolve_precision("float32") == "float32"


def test_the_cpu_answers_are_booleans():
    assert isinstance(precision.amx_tiles(), bool) and isinstance(precision.native_bfloat16(), bool)
    assert not precision.amx_tiles() or precision.native_bfloat16()  # AMX tiles compute bfloat16 natively
