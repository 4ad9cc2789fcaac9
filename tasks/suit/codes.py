"""Reading the codes (Chen et al. 2021, §3.2 "RejectorNet" and "RecogNet", §4.2): which candidate quads are coded
squares of the suit, and which code each carries, in which orientation.

Each candidate quad is warped to a 104 x 104 crop (tasks/suit/quads.py), its vertex 0 at the crop's top-left.
``RejectorNet`` gives one logit: a white square of the suit with a legible code, or not. ``RecogNet`` reads an
accepted crop: the quarter turn ``rotation`` r (quad vertex i is the upright code's corner (i + r) mod 4; a crop
of rotation r shows the code turned r quarter turns counter-clockwise) and the code's two characters as read
upright, each one of the 25 of the alphabet. RejectorNet sees the crop average-pooled to 26 x 26, RecogNet to
52 x 52 (the glyphs are half a square tall, about 20 px there; a square spans 10-50 px in the studio's images), so
both stay small enough for a CPU core to read a few hundred quads per image.

Training crops come from two sources. ``synthetic_quads`` prints a 3 x 3 patch of the board with the suit's own
glyphs (pattern.print_code) around a random code, films it under a random homography at 10-50 px per square
with lighting, blur and noise, and warps the corners (plus detection noise) back: every one of the 625 codes in
every rotation, as the paper trains RecogNet on synthetic crops. ``quad_samples`` cuts the candidate quads of a
studio image whose corners were detected by CornerdetNet and labels each from the truth: a coded square's four
corners, in some rotation, or not. RejectorNet learns from both (the studio's negatives are the real ones: quads
through false detections on glyphs, across seams, uncoded squares), with the paper's aggressive photometric
augmentation.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import cv2
import numpy as np

from mocapflow.tasks.suit.augment import Augment, Fitted, adam_cosine, augment_crops, fit, seeded
from mocapflow.tasks.suit.crop_pool import CropPool
from mocapflow.tasks.suit.metrics import quad_truth
from mocapflow.tasks.suit.pattern import ALPHABET, BLACK, WHITE, level, print_code
from mocapflow.tasks.suit.net_configs import N_CHARS, CodeError, CodeNetConfig
from mocapflow.tasks.suit.quads import CROP, warp_quads

if TYPE_CHECKING:
    import torch

    from mocapflow.tasks.suit.networks import RecogNet, RejectorNet



def code_index(code: str) -> int:
    """'AB' -> first * 25 + second (indices in the alphabet)."""
    return ALPHABET.index(code[0]) * N_CHARS + ALPHABET.index(code[1])


def code_text(index: int) -> str:
    return ALPHABET[index // N_CHARS] + ALPHABET[index % N_CHARS]


# ---------------------------------------------------------------------------------------------------- networks

def net_config(architecture: dict) -> CodeNetConfig:
    return CodeNetConfig(widths=tuple(architecture["widths"]), hidden=int(architecture["hidden"]),
                         pool=int(architecture["pool"]))


def to_input(crops: np.ndarray) -> torch.Tensor:
    """(n, 104, 104) uint8 -> (n, 1, 104, 104) float in [0, 1]."""
    import torch

    return torch.from_numpy(np.ascontiguousarray(crops)).float().div_(255.0)[:, None]


# ------------------------------------------------------------------------------------------------------ reading

PRECISIONS = ("auto", "float32", "bfloat16")


@dataclass(frozen=True)
class ReadConfig:
    # RejectorNet's logit at least this (0: probability 1/2). Chosen with the shipped networks (trained on every
    # coded square, training/suit_long.yaml) on the tuning split by benchmarks/suit_networks_tune.py: readable
    # corners labelled right 75.16 -> 78.08 %, wrong labels 0.298 -> 0.276 % (the former networks at 0)
    accept: float = 2.0
    min_confidence: float = 0.5  # RecogNet's probability of rotation x code, at least
    batch: int = 512  # crops per network call: an image's candidates at once (smaller batches were slower)
    # "bfloat16": both networks under torch's bfloat16 autocast, 1.6x faster with AMX tiles; "auto": bfloat16 where
    # the CPU has them, float32 elsewhere (tasks/shared/precision.py). Chosen on the validation take: readable
    # corners labelled 75.34 -> 75.52 %, wrong labels 24 -> 24 (docs/suit.md)
    precision: str = "auto"

    def __post_init__(self):
        if self.precision not in PRECISIONS or self.batch < 1:
            raise CodeError(f"precision must be one of {PRECISIONS} (got {self.precision!r}) and batch >= 1 "
                            f"(got {self.batch})")


@dataclass(frozen=True)
class Readings:
    accepted: np.ndarray  # (q,) bool
    rotation: np.ndarray  # (q,) int8, -1 rejected
    code: np.ndarray  # (q,) int16, -1 rejected
    confidence: np.ndarray  # (q,) float32


def read_crops(crops: np.ndarray, rejector: RejectorNet, recog: RecogNet, config: ReadConfig = ReadConfig()) -> Readings:
    """RejectorNet then RecogNet on the accepted crops, all of an image's at once (``config.batch``), in
    ``config.precision``; networks.for_inference copies of the two read the same 3.4x faster in float32.
    crops (q, 104, 104) uint8"""
    import torch
    from torch.nn import functional as F

    from mocapflow.tasks.shared.precision import resolve_precision

    q = len(crops)
    accepted = np.zeros(q, bool)
    rotation, code = np.full(q, -1, np.int8), np.full(q, -1, np.int16)
    confidence = np.zeros(q, np.float32)
    low = torch.autocast("cpu", dtype=torch.bfloat16, enabled=resolve_precision(config.precision) == "bfloat16")
    with torch.inference_mode(), low:
        for lo in range(0, q, config.batch):
            x = to_input(crops[lo:lo + config.batch])
            keep = (rejector(x).float() >= config.accept).numpy()
            if not keep.any():
                continue
            rot, first, second = (y.float() for y in recog(x[torch.from_numpy(keep)]))
            p_rot, r = F.softmax(rot, 1).max(1)
            p_a, a = F.softmax(first, 1).max(1)
            p_b, b = F.softmax(second, 1).max(1)
            p = (p_rot * p_a * p_b).numpy()
            idx = lo + np.flatnonzero(keep)
            good = p >= config.min_confidence
            accepted[idx[good]] = True
            rotation[idx[good]] = r.numpy()[good]
            code[idx[good]] = (a * N_CHARS + b).numpy()[good]
            confidence[idx] = p
    return Readings(accepted, rotation, code, confidence)


# ------------------------------------------------------------------------------------------- synthetic crops

@dataclass(frozen=True)
class SynthConfig:
    """Films of a 3 x 3 patch of the board around a coded square (§4.2: synthetic crops for RecogNet)."""

    texels: int = 64  # texels per square of the printed patch
    square_px: tuple[float, float] = (10.0, 50.0)  # the square's side in the image
    shear: float = 0.18  # corner jitter of the filmed square, in squares
    squash: float = 0.55  # foreshortening: one axis scaled by [1 - squash, 1]
    detection_px: float = 0.3  # noise on the corners the crop is warped from
    gain: tuple[float, float] = (0.35, 1.15)  # lighting, x albedo x 255
    noise: tuple[float, float] = (1.0, 6.0)  # Gaussian sigma, grey levels
    blur: tuple[float, float] = (0.0, 1.3)  # Gaussian sigma, image px
    negative_share: float = 0.3  # crops of black squares and off-grid quads (RejectorNet's negatives)


@dataclass(frozen=True)
class QuadSamples:
    crops: np.ndarray  # (n, 104, 104) uint8
    valid: np.ndarray  # (n,) bool: a coded square
    rotation: np.ndarray  # (n,) int8, -1 invalid
    code: np.ndarray  # (n,) int16, -1 invalid

    def __len__(self) -> int:
        return len(self.crops)


def concat_quad_samples(parts: list[QuadSamples]) -> QuadSamples:
    return QuadSamples(*(np.concatenate([getattr(p, f) for p in parts]) for f in ("crops", "valid", "rotation", "code")))


def board_patch(codes: list[str], texels: int) -> np.ndarray:
    """A 3 x 3 patch of the board (uint8, 3t x 3t): the centre and corner squares white with codes[0..4], the edge
    squares black, as pattern.texture prints them (blurred like the studio's print)."""
    t = texels
    patch = np.full((3 * t, 3 * t), level(BLACK), np.uint8)
    whites = ((1, 1), (0, 0), (0, 2), (2, 0), (2, 2))  # (row, column) of squares
    for (r, c), code in zip(whites, codes):
        patch[r * t:(r + 1) * t, c * t:(c + 1) * t] = level(WHITE)
        print_code(patch, code, c * t, (r + 1) * t, t)
    return cv2.GaussianBlur(patch, (0, 0), 0.7 * t / 33)


def synthetic_quads(n: int, config: SynthConfig, rng: np.random.Generator) -> QuadSamples:
    """``n`` crops: films of board patches with their centre square's corners (or a negative's) warped back."""
    crops = np.empty((n, CROP, CROP), np.uint8)
    valid = rng.random(n) >= config.negative_share
    rotation = np.where(valid, rng.integers(0, 4, n), -1).astype(np.int8)
    code = np.where(valid, rng.integers(0, N_CHARS ** 2, n), -1).astype(np.int16)
    t = config.texels
    for i in range(n):
        codes = [code_text(int(code[i]) if valid[i] else int(rng.integers(N_CHARS ** 2)))] + \
                [code_text(int(c)) for c in rng.integers(0, N_CHARS ** 2, 4)]
        patch = board_patch(codes, t)
        quad_tex = _quad_in_patch(valid[i], t, rng)  # (4, 2) clockwise from the upright top-left, texels
        image, quad_img = _film(patch, quad_tex, config, rng)
        detected = quad_img + config.detection_px * rng.standard_normal((4, 2))
        r = int(rotation[i]) if valid[i] else int(rng.integers(4))
        crops[i] = warp_quads(image, np.roll(detected, -r, axis=0)[None])[0]
    return QuadSamples(crops, valid, rotation, code)


def _quad_in_patch(valid: bool, t: int, rng: np.random.Generator) -> np.ndarray:
    """The centre white square's corners (TL, TR, BR, BL in patch pixels; edges on texel boundaries), or a negative:
    a black square, or a quad off the grid by a fraction of a square."""
    square = np.array([(t, t), (2 * t, t), (2 * t, 2 * t), (t, 2 * t)], float) - 0.5
    if valid:
        return square
    kind = rng.integers(3)
    if kind == 0:  # the black square right of the centre
        return square + (t, 0)
    if kind == 1:  # shifted off the grid
        return square + rng.uniform(0.25, 0.6, 2) * t * rng.choice([-1, 1], 2)
    return square + rng.uniform(-0.35, 0.35, (4, 2)) * t  # a distorted quad around the centre


def _film(patch: np.ndarray, quad_tex: np.ndarray, config: SynthConfig, rng: np.random.Generator
          ) -> tuple[np.ndarray, np.ndarray]:
    """The patch under a random homography that makes the quad's square about square_px wide, lit, blurred and
    noisy.  -> image (h, w) uint8, the quad's corners in it (4, 2)"""
    side = rng.uniform(*config.square_px)
    angle = rng.uniform(0, 2 * np.pi)
    squash = np.diag([1.0, 1.0 - rng.uniform(0, config.squash)])
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    t = patch.shape[0] / 3
    unit = np.array([(-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)])  # the centre square, in squares
    target = (unit + config.shear * rng.uniform(-1, 1, (4, 2))) @ (rot @ squash).T * side
    centre_sq = (np.array([(t, t), (2 * t, t), (2 * t, 2 * t), (t, 2 * t)]) - 0.5).astype(np.float32)
    size = int(np.ceil(4.5 * side))
    target = target + size / 2
    h = cv2.getPerspectiveTransform(centre_sq, target.astype(np.float32))
    light = rng.uniform(*config.gain)
    patch = cv2.GaussianBlur(patch.astype(np.float32), (0, 0), 0.45 * t / side)  # no aliasing when shrunk
    image = cv2.warpPerspective(patch * light, h, (size, size), flags=cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=float(level(BLACK)) * light)
    sigma = rng.uniform(*config.blur)
    if sigma > 0.3:
        image = cv2.GaussianBlur(image, (0, 0), sigma)
    ramp = 1 + 0.3 * rng.uniform(-1, 1) * (np.arange(size) / size - 0.5)  # a lighting gradient across the patch
    image = image * ramp[None, :] + rng.uniform(*config.noise) * rng.standard_normal(image.shape)
    quad_img = cv2.perspectiveTransform(quad_tex[None].astype(np.float32), h)[0].astype(np.float64)
    return np.clip(np.round(image), 0, 255).astype(np.uint8), quad_img


# ------------------------------------------------------------------------------------------------ studio crops

def label_quads(xy: np.ndarray, quads: np.ndarray, truth: np.ndarray, visible: np.ndarray,
                square_corners: np.ndarray, codes: list[str], match_px: float = 1.5
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Truth for candidate quads: a coded square's four corners, each detection within ``match_px`` of one.
    xy (n, 2) detections, quads (q, 4) clockwise detection indices, truth (corner, 2), visible (corner,),
    square_corners (square, 4) -> valid (q,) bool, rotation (q,) int8, code (q,) int16 (-1 invalid)"""
    square, rotation = quad_truth(xy, quads, truth, visible, square_corners, match_px)
    numbers = np.array([code_index(c) for c in codes], np.int16)
    valid = square >= 0
    return valid, rotation.astype(np.int8), np.where(valid, numbers[np.maximum(square, 0)], -1).astype(np.int16)


# --------------------------------------------------------------------------------------------------- training

@dataclass(frozen=True)
class CodeTrainConfig:
    rejector: CodeNetConfig = CodeNetConfig()
    recog: CodeNetConfig = CodeNetConfig(widths=(24, 48, 64, 96), hidden=192, pool=2)
    augment: Augment = Augment(contrast=(0.4, 1.4), brightness=0.2, gamma=(0.5, 2.0), noise=(0.0, 0.04),
                               blur=(0.0, 1.5), blur_share=0.5)  # §4.2: aggressive for the codes
    jitter: float = 0.04  # random affine per crop: rotation (rad), scale and shift (of the crop) up to this
    iterations: int = 8000
    batch: int = 128
    learning_rate: float = 2e-3
    synthetic: int = 20000  # synthetic crops drawn besides the studio's
    synth: SynthConfig = field(default_factory=SynthConfig)

    def __post_init__(self):
        if self.iterations < 1 or self.batch < 2 or self.learning_rate <= 0 or self.synthetic < 0:
            raise CodeError(f"iterations ({self.iterations}) >= 1, batch ({self.batch}) >= 2, learning_rate "
                            f"({self.learning_rate}) > 0 and synthetic ({self.synthetic}) >= 0 needed")


def _jitter(x: torch.Tensor, amount: float, gen: torch.Generator) -> torch.Tensor:
    """A small random affine map per crop (the detected corners' own error), border replicated."""
    import torch
    from torch.nn import functional as F

    n = len(x)
    u = (torch.rand(n, 5, generator=gen) * 2 - 1) * amount
    c, s = torch.cos(u[:, 0]), torch.sin(u[:, 0])
    scale = 1 + u[:, 1]
    theta = torch.stack([torch.stack([c * scale, -s * scale, u[:, 2] * 2], 1),
                         torch.stack([s * scale, c * scale, u[:, 3] * 2], 1)], 1)
    grid = F.affine_grid(theta.to(x.device), list(x.shape), align_corners=False)
    return F.grid_sample(x, grid, mode="bilinear", padding_mode="border", align_corners=False)


def train_code_nets(samples: QuadSamples | CropPool, config: CodeTrainConfig = CodeTrainConfig(), seed: int = 0,
                    checkpoint=None, checkpoint_every: int = 500,
                    start: tuple[RejectorNet, RecogNet] | None = None) -> tuple[RejectorNet, RecogNet, Fitted]:
    """RejectorNet on every crop, RecogNet on the valid ones, jointly per iteration (Adam, cosine decay), each
    batch augmented; ``samples`` in memory or a pool streaming them; checkpointed and resumable with a
    ``checkpoint`` (augment.fit); from the weights of ``start`` (fine-tuning; of the config's architectures) or
    from scratch.  -> the two networks (eval mode, CPU), the losses and seconds"""
    import torch
    from torch.nn import functional as F
    from mocapflow.tasks.suit.networks import RecogNet, RejectorNet

    pool = samples if isinstance(samples, CropPool) else CropPool.in_memory(
        {"crops": samples.crops, "valid": samples.valid, "rotation": samples.rotation, "code": samples.code})
    valid = pool.count("valid")
    if len(pool) < config.batch or valid == len(pool) or not valid:
        raise CodeError(f"training needs at least one batch ({config.batch}) of crops with valid and invalid ones; "
                        f"got {len(pool)}, {valid} valid")
    gen, rng, device = seeded(seed, 104)
    if start is None:
        start = RejectorNet(config.rejector), RecogNet(config.recog)
    differ = [f"{name} {net.config} in the file, {want} here" for name, net, want in
              (("rejector", start[0], config.rejector), ("recog", start[1], config.recog)) if net.config != want]
    if differ:
        raise CodeError(f"the networks to start from are another architecture ({'; '.join(differ)}); set the "
                        "training's networks to the file's or train from scratch (init: \"\")")
    rejector, recog = start[0].to(device), start[1].to(device)
    opt, sched = adam_cosine(list(rejector.parameters()) + list(recog.parameters()), config.learning_rate,
                             config.iterations)

    def batch_loss():
        b = pool.draw(rng, config.batch)
        x = _prepare(torch.from_numpy(b["crops"]).to(device), config, gen)
        loss = F.binary_cross_entropy_with_logits(rejector(x), torch.from_numpy(b["valid"]).float().to(device))
        b = pool.draw(rng, config.batch, where="valid")
        rot, first, second = recog(_prepare(torch.from_numpy(b["crops"]).to(device), config, gen))
        c = torch.from_numpy(b["code"].astype(np.int64)).to(device)
        rotation = torch.from_numpy(b["rotation"].astype(np.int64)).to(device)
        return loss + F.cross_entropy(rot, rotation) + F.cross_entropy(first, c // N_CHARS) \
            + F.cross_entropy(second, c % N_CHARS)

    fitted = fit({"rejector": rejector, "recog": recog}, batch_loss, optimizer=opt, schedule=sched,
                 iterations=config.iterations, pool=pool, streams=(gen, rng), device=device, checkpoint=checkpoint,
                 checkpoint_every=checkpoint_every)
    return rejector, recog, fitted


def _prepare(crops: torch.Tensor, config: CodeTrainConfig, gen: torch.Generator) -> torch.Tensor:
    x = crops.float().div_(255.0)[:, None]
    return augment_crops(_jitter(x, config.jitter, gen), config.augment, gen)


# ---------------------------------------------------------------------------------------------------- the stage

@dataclass(frozen=True)
class ReadCodesConfig:
    read: ReadConfig = ReadConfig()
    weights: str = ""  # a file with both networks; empty: the packaged one


def nets_from_weights(weights: dict) -> tuple[RejectorNet, RecogNet]:
    """Both networks of a weights file ({"architecture": {"rejector", "recog"}, "state"}; the state's names
    prefixed ``rejector.`` and ``recog.``), in eval mode."""
    from mocapflow.tasks.suit.networks import RecogNet, RejectorNet

    arch, state = weights["architecture"], weights["state"]
    rejector, recog = RejectorNet(net_config(arch["rejector"])), RecogNet(net_config(arch["recog"]))
    for name, net in (("rejector", rejector), ("recog", recog)):
        net.load_state_dict({k[len(name) + 1:]: t for k, t in state.items() if k.startswith(name + ".")})
    return rejector.eval(), recog.eval()


def pack_state(rejector: RejectorNet, recog: RecogNet) -> tuple[dict, dict]:
    """-> (state with prefixed names, architecture) for tasks/shared/weights.pack."""
    state = {f"rejector.{k}": t for k, t in rejector.state_dict().items()}
    state.update({f"recog.{k}": t for k, t in recog.state_dict().items()})
    arch = {name: {"widths": list(net.config.widths), "hidden": net.config.hidden, "pool": net.config.pool}
            for name, net in (("rejector", rejector), ("recog", recog))}
    return state, arch


def read_codes(images, corners, quads, config: ReadCodesConfig, weights: dict):
    """Task: suit_codes of every candidate quad of every view and frame (§3.2)."""
    import torch

    import xarray as xr

    from mocapflow.tasks.suit.networks import for_inference

    rejector, recog = (for_inference(net) for net in nets_from_weights(weights))
    torch.set_num_threads(1)
    views, frames = images["view"].values, images["frame"].values
    shape = quads["detections"].shape[:3]
    accepted, confidence = np.zeros(shape, bool), np.zeros(shape, np.float32)
    rotation, code = np.full(shape, -1, np.int8), np.full(shape, -1, np.int16)
    for v in range(len(views)):
        for f in range(len(frames)):
            det = quads["detections"].values[v, f]
            n = int((det[:, 0] >= 0).sum())
            if not n:
                continue
            xy = np.column_stack([corners["x"].values[v, f], corners["y"].values[v, f]])
            read = read_crops(warp_quads(images["image"].values[v, f], xy[det[:n]]), rejector, recog, config.read)
            accepted[v, f, :n], rotation[v, f, :n] = read.accepted, read.rotation
            code[v, f, :n], confidence[v, f, :n] = read.code, read.confidence
    dims = ("view", "frame", "quad")
    return xr.Dataset({"accepted": (dims, accepted), "rotation": (dims, rotation), "code": (dims, code),
                       "confidence": (dims, confidence)}, coords={"view": views, "frame": frames})
