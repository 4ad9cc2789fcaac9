"""The code networks: the shipped RejectorNet and RecogNet read warped quads of known codes in every rotation and
refuse what is not a coded square; a crop of rotation r is the upright crop turned r quarter turns; the weights
file round-trips through torch.load(weights_only=True)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from mocapflow.tasks.shared.weights import pack, unpack
from mocapflow.tasks.suit import codes as cd

WEIGHTS = Path(__file__).resolve().parents[3] / "models" / "suit_codes.pt"


@pytest.fixture(scope="module")
def nets():
    torch.set_num_threads(1)
    return cd.nets_from_weights(torch.load(WEIGHTS, weights_only=True))


def test_shipped_networks_read_known_codes_in_every_rotation(nets):
    rng = np.random.default_rng(4242)  # crops the training never drew (it draws from seed 301)
    config = cd.SynthConfig(square_px=(24.0, 45.0), noise=(1.0, 3.0), blur=(0.0, 0.8), negative_share=0.25)
    s = cd.synthetic_quads(400, config, rng)
    read = cd.read_crops(s.crops, *nets)
    valid = s.valid
    assert read.accepted[valid].mean() > 0.9
    assert read.accepted[~valid].mean() < 0.05
    ok = read.accepted & valid
    assert (read.rotation[ok] == s.rotation[ok]).mean() > 0.98
    assert (read.code[ok] == s.code[ok]).mean() > 0.95
    assert set(s.rotation[valid].tolist()) == {0, 1, 2, 3}


def test_a_rotation_is_the_upright_crop_turned():
    patch = cd.board_patch(["AB", "12", "34", "56", "78"], 64)
    quad = np.array([(64, 64), (128, 64), (128, 128), (64, 128)], float) - 0.5
    from mocapflow.tasks.suit.quads import warp_quads
    upright = warp_quads(patch, quad[None])[0]
    for r in range(4):
        turned = warp_quads(patch, np.roll(quad, -r, axis=0)[None])[0]
        assert np.abs(turned.astype(int) - np.rot90(upright, r).astype(int)).max() <= 1


def test_codes_and_their_numbers():
    assert cd.code_index("11") == 0 and cd.code_index("YY") == 624
    assert all(cd.code_text(cd.code_index(c)) == c for c in ("A7", "Y1", "QK"))


def test_weights_round_trip(tmp_path, nets):
    state, arch = cd.pack_state(*nets)
    path = tmp_path / "codes.pt"
    torch.save(unpack(pack(state, arch, {"seed": 0}, [1.0])), path)
    rejector, recog = cd.nets_from_weights(torch.load(path, weights_only=True))
    x = torch.rand(3, 1, cd.CROP, cd.CROP)
    with torch.no_grad():
        assert torch.equal(rejector(x), nets[0](x))
        assert all(torch.equal(a, b) for a, b in zip(recog(x), nets[1](x)))
