"""The corner detector: its whole-image pass equals the network on each cell's crop, clustering keeps the stronger of
two close detections, training crops carry the right labels, a tiny training finds corners drawn at known sub-pixel
positions, and bad images are refused with the fix named. The images are warped checkerboards drawn with OpenCV."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from mocapflow.tasks.suit import corners as co
from mocapflow.tasks.suit import networks

HI = 64  # px per square of the high-resolution board


def board(rng: np.random.Generator, size=(160, 200), squares=(6, 7), square_px=22.0, tilt=0.25, noise=2.0):
    """A checkerboard turned, scaled and tilted in perspective onto a dark background, sensor noise added.
    -> image (y, x) uint8 and its interior corners (n, 2) (x, y) where the warp puts them"""
    ny, nx = squares
    yy, xx = np.mgrid[0:ny * HI, 0:nx * HI]
    hires = np.where((yy // HI + xx // HI) % 2 == 0, 200.0, 20.0).astype(np.float32)
    scale = square_px / HI
    hires = cv2.GaussianBlur(hires, (0, 0), 0.5 / scale)  # band-limited before it is sampled
    a = rng.uniform(0, 2 * np.pi)
    h, w = size
    affine = np.eye(3)
    affine[:2, :2] = scale * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    affine[:2, 2] = np.array([w, h]) / 2 + rng.uniform(-3, 3, 2) - affine[:2, :2] @ (np.array([nx, ny]) * HI / 2 - 0.5)
    tilt_m = np.eye(3)
    tilt_m[2, :2] = rng.uniform(-tilt, tilt, 2) / (nx * HI)
    centre = np.eye(3)
    centre[:2, 2] = -np.array([w, h]) / 2
    warp = np.linalg.inv(centre) @ tilt_m @ centre @ affine
    img = cv2.warpPerspective(hires, warp, (w, h), flags=cv2.INTER_LINEAR, borderValue=10.0)
    img = np.clip(np.rint(img + noise * rng.standard_normal(img.shape)), 0, 255).astype(np.uint8)
    gi, gj = np.mgrid[1:nx, 1:ny]
    grid = np.column_stack([gi.ravel(), gj.ravel()]) * HI - 0.5  # pixel centres at integers: edges at k HI - 0.5
    return img, cv2.perspectiveTransform(grid[None], warp)[0]


def small_net(seed=0) -> networks.CornerdetNet:
    torch.manual_seed(seed)
    return networks.CornerdetNet(co.CornerNetConfig((8, 16, 32, 32), 32)).eval()


def test_whole_image_pass_equals_the_network_on_each_cells_crop():
    net = small_net()
    for p in net.parameters():  # the untrained output is nearly flat: make every weight count
        p.data.normal_(0, 0.5)
    image = np.random.default_rng(0).integers(0, 256, (45, 70), dtype=np.uint8)  # neither side a multiple of 8
    cells = co.cell_outputs(image, net, co.DetectConfig(min_contrast=0, tile_cells=3))
    assert cells.logit.shape == (6, 9)
    padded = cv2.copyMakeBorder(image, 6, 30, 6, 30, cv2.BORDER_REPLICATE)
    crops = np.stack([padded[8 * i:8 * i + 20, 8 * j:8 * j + 20] for i in range(6) for j in range(9)])
    one_by_one = co.crop_outputs(net, crops).reshape(6, 9, 3)
    np.testing.assert_allclose(cells.logit, one_by_one[..., 0], rtol=1e-4, atol=1e-4)
    cols, rows = np.meshgrid(np.arange(9), np.arange(6))
    np.testing.assert_allclose(cells.xy[..., 0], 8 * cols - 0.5 + 8 * one_by_one[..., 1], atol=1e-3)
    np.testing.assert_allclose(cells.xy[..., 1], 8 * rows - 0.5 + 8 * one_by_one[..., 2], atol=1e-3)
    # a pixel outside a cell's 20 x 20 crop does not change that cell's output
    changed = image.copy()
    changed[30, 40] = 255 - changed[30, 40]  # in the crops of cells (rows 3-4, columns 4-5) only
    again = co.cell_outputs(changed, net, co.DetectConfig(min_contrast=0, tile_cells=3)).logit
    moved = np.argwhere(np.abs(again - cells.logit) > 1e-6)
    assert {tuple(x) for x in moved} <= {(3, 4), (3, 5), (4, 4), (4, 5)} and len(moved) > 0


def test_flat_cells_are_skipped():
    image = np.full((64, 64), 12, np.uint8)
    image[30:50, 30:50] = 200
    cells = co.cell_outputs(image, small_net(), co.DetectConfig(min_contrast=40))
    looked = np.isfinite(cells.logit)
    assert looked[4, 4] and not looked[0, 0] and 0 < looked.sum() < looked.size


def test_clustering_keeps_the_higher_logit_of_close_detections():
    xy = np.array([[10.0, 10.0], [11.5, 10.5], [30.0, 30.0], [33.5, 30.0], [60.0, 60.0], [62.0, 60.0], [64.0, 60.0]])
    logit = np.array([1.0, 2.0, 0.5, 0.7, 3.0, 1.0, 2.0])
    kept = co.cluster_corners(xy, logit, 3.0)
    # 0 and 1 are 1.6 px apart: 1 stays; 2 and 3 are 3.5 px apart: both stay; 5 is within 2 px of 4 and of 6, which
    # are 4 px apart: 4 (the highest) takes 5 away, then 6 stays
    assert sorted(kept.tolist()) == [1, 2, 3, 4, 6]
    assert kept[0] == 4  # highest first
    assert co.cluster_corners(xy[:1], logit[:1], 3.0).tolist() == [0]


class BrightestPixel(torch.nn.Module):
    """A stand-in network: 'the corner' is the brightest pixel of the crop, at its centre."""

    def forward(self, x):
        n, _, h, w = x.shape
        flat = x.reshape(n, -1).argmax(dim=1)
        u, v = (flat % w - 5.5) / 8, (flat // w - 5.5) / 8
        return torch.stack([torch.ones(n), u, v], dim=1)[:, :, None, None]


def test_refinement_averages_turned_and_shifted_crops_in_image_coordinates():
    image = np.full((60, 80), 10, np.uint8)
    spots = np.array([[30, 20], [9, 41], [70, 50]])  # (x, y)
    image[spots[:, 1], spots[:, 0]] = 250
    start = spots + np.array([[1.4, -0.8], [-1.2, 1.1], [0.6, 0.3]])  # the first guesses, off by a pixel or so
    refined = co.refine_corners(image, start, BrightestPixel().eval(), co.DetectConfig(recrops=16))
    np.testing.assert_allclose(refined, spots, atol=1e-6)  # every shift and turn undone exactly


def _origin(image, crop):
    """Where an exact crop was cut: its top-left pixel (x, y)."""
    res = cv2.matchTemplate(image.astype(np.float32), crop.astype(np.float32), cv2.TM_SQDIFF)
    y, x = np.unravel_index(np.argmin(res), res.shape)
    assert np.array_equal(image[y:y + 20, x:x + 20], crop), "an exact cut is an exact copy of the image"
    return np.array([x, y])


def test_samples_are_labelled_by_the_corner_in_their_central_cell():
    rng = np.random.default_rng(3)
    image, corners = board(rng)
    config = co.SampleConfig(per_corner=3, rotate=0.0)
    s = co.corner_samples(image, corners, np.ones(len(corners), bool), config, rng)
    pos, neg = np.flatnonzero(s.present), np.flatnonzero(~s.present)
    assert len(pos) == 3 * len(corners) and len(neg) == 2 * len(pos)
    assert set(np.unique(s.kind[neg])) == {1, 2, 3} and (s.kind[pos] == 0).all()
    padded = cv2.copyMakeBorder(image, 20, 20, 20, 20, cv2.BORDER_REPLICATE)
    for k in pos:
        at = corners - (_origin(padded, s.crops[k]) - 20)  # every corner in this crop's coordinates
        inside = ((at >= 5.5) & (at < 13.5)).all(axis=1)
        assert inside.sum() == 1
        np.testing.assert_allclose(s.position[k], (at[inside][0] - 5.5) / 8, atol=1e-5)
    for k in neg[::5]:
        at = corners - (_origin(padded, s.crops[k]) - 20)
        assert not ((at >= 5.5 - config.ignore_px) & (at < 13.5 + config.ignore_px)).all(axis=1).any()
    # turned crops: the target is where the corner shows in the crop (OpenCV's saddle refinement agrees)
    s = co.corner_samples(image, corners, np.ones(len(corners), bool), co.SampleConfig(per_corner=2, rotate=1.0),
                          rng)
    p = s.position[s.present] * 8 + 5.5
    found = np.stack([cv2.cornerSubPix(c.astype(np.float32), q[None, None].astype(np.float32).copy(), (3, 3),
                                       (-1, -1), (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-3))[0, 0]
                      for c, q in zip(s.crops[s.present], p)])
    assert np.median(np.linalg.norm(found - p, axis=1)) < 0.15


def test_crowded_and_hidden_corners_are_not_positives():
    rng = np.random.default_rng(4)
    image, corners = board(rng)
    visible = np.ones(len(corners), bool)
    visible[0] = False
    crowded = np.concatenate([corners, corners[1:2] + [5.0, 0.0]])  # a second corner 5 px from corner 1
    s = co.corner_samples(image, crowded, np.append(visible, True), co.SampleConfig(per_corner=1), rng)
    assert s.present.sum() == len(corners) - 2  # neither 0 (hidden), nor 1 and its crowding neighbour
    only = np.zeros(len(corners), bool)
    only[5:8] = True
    s = co.corner_samples(image, corners, visible, co.SampleConfig(per_corner=2), rng, positive=only)
    assert s.present.sum() == 6


@pytest.fixture(scope="module")
def tiny_net():
    rng = np.random.default_rng(1)
    parts = []
    for _ in range(6):
        image, corners = board(rng, square_px=rng.uniform(16, 26))
        parts.append(co.corner_samples(image, corners, np.ones(len(corners), bool), co.SampleConfig(per_corner=8),
                                       rng))
    samples = co.concat_samples(parts)
    config = co.TrainConfig(net=co.CornerNetConfig((8, 16, 32, 32), 32), iterations=600, batch=64,
                            learning_rate=1e-2)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # a small network trains fastest on one thread
    try:
        return co.train_cornerdet(samples, config, seed=0)[0]
    finally:
        torch.set_num_threads(threads)


def test_a_tiny_training_finds_corners_at_their_sub_pixel_positions(tiny_net):
    image, corners = board(np.random.default_rng(99), square_px=21.0)
    found = co.detect_corners(image, tiny_net, co.DetectConfig())
    d = np.linalg.norm(found.xy[None] - corners[:, None], axis=2)  # (true, found)
    nearest = d.min(axis=1)
    assert (nearest < 0.5).mean() >= 0.9 and np.median(nearest) < 0.3
    pair = np.linalg.norm(found.xy[None] - found.xy[:, None], axis=2)
    assert (pair[np.triu_indices(len(found.xy), 1)] >= 3.0).all()  # clustered
    again = co.detect_corners(image, tiny_net, co.DetectConfig())
    np.testing.assert_array_equal(found.xy, again.xy)  # the re-crops are seeded
    assert found.logit.shape == (len(found.xy),)


def test_training_is_deterministic_for_a_seed():
    rng = np.random.default_rng(2)
    image, corners = board(rng)
    samples = co.corner_samples(image, corners, np.ones(len(corners), bool), co.SampleConfig(), rng)
    config = co.TrainConfig(net=co.CornerNetConfig((4, 4, 4, 4), 4), iterations=5, batch=16)
    a, b = (co.train_cornerdet(samples, config, seed=7)[0].state_dict() for _ in range(2))
    c = co.train_cornerdet(samples, config, seed=8)[0].state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a) and not all(torch.equal(a[k], c[k]) for k in a)
    rebuilt = networks.CornerdetNet(config.net)
    rebuilt.load_state_dict(a)  # rebuilt from the config alone


def test_bad_images_are_refused_with_the_fix():
    net = small_net()
    grey = np.zeros((40, 40), np.uint8)
    with pytest.raises(co.CornerError, match="cvtColor"):
        co.detect_corners(np.zeros((40, 40, 3), np.uint8), net)
    with pytest.raises(co.CornerError, match="at least 20 x 20"):
        co.detect_corners(np.zeros((12, 40), np.uint8), net)
    with pytest.raises(co.CornerError, match="astype"):
        co.detect_corners(grey.astype(np.float32), net)
    with pytest.raises(co.CornerError, match=r"net.eval\(\)"):
        co.detect_corners(grey, net.train())
    with pytest.raises(co.CornerError, match="cvtColor"):
        co.corner_samples(np.zeros((40, 40, 3), np.uint8), np.zeros((1, 2)), np.ones(1, bool), co.SampleConfig(),
                          np.random.default_rng(0))
    with pytest.raises(co.CornerError, match=r"\(corner, 2\)"):
        co.corner_samples(grey, np.zeros((2, 3)), np.ones(2, bool), co.SampleConfig(), np.random.default_rng(0))
