"""Per-pixel in-focus probability without learned weights: Zhuo & Sim (2011) edge-based defocus.

Zhuo, S. & Sim, T. "Defocus map estimation from a single image", Pattern Recognition 44 (2011).
A step edge blurred by a Gaussian of unknown sigma has gradient maximum A / (sqrt(2 pi) sigma);
re-blurring with a known sigma0 gives A / (sqrt(2 pi) sqrt(sigma^2 + sigma0^2)). The ratio R of
the two maxima at an edge therefore gives sigma = sigma0 / sqrt(R^2 - 1), independently of the
edge's contrast A. The sparse estimates at edges are then propagated to every pixel (the paper
uses matting-Laplacian interpolation; here normalised convolution + a guided filter, which is
O(pixels) and ~100x faster).

Steps (work resolution: the frame downscaled to `focus_work_width_px`, so the sigma threshold is
a fixed fraction of the frame width whatever the input resolution — "calibrated per
resolution" by construction; a frame narrower than that is used as is and the threshold scaled):
1. grey image I, re-blurred I1 = I * G(sigma0);
2. edges: Canny on I (non-maximum-suppressed, hysteresis on the gradient magnitude);
3. at edges, R = |grad I| / |grad I1| -> sigma -> P(in focus) = logistic((thr - sigma) / soft);
   weight = edge contrast (strong edges are more reliable);
4. propagate to the map resolution: normalised Gaussian convolution of weight*P over weight,
   pulled towards `focus_no_edge_prior` where there are no edges nearby (a large area with no
   edge at all is most often blurred, but could be a flat sharp wall: the prior says how much to
   believe the former), then a guided filter with the grey image as guide so that the map
   follows object boundaries.

All-sharp frames have small sigma at every edge -> mostly in focus; all-blurred frames have
large sigma or no edges at all -> mostly out of focus (an Otsu split of a sharpness map would
cut either in two).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from cinetransfer.services.detector.config import DetectorConfig


@dataclass(frozen=True)
class FocusResult:
    prob: np.ndarray  # float32 (h, w) in [0, 1] at map resolution
    sigma_edges: np.ndarray  # float32 sigmas at the edge pixels [work px] (diagnostics)
    scale: float  # map width / frame width

    def as_uint8(self) -> np.ndarray:
        return np.clip(np.rint(self.prob * 255.0), 0, 255).astype(np.uint8)


def _box(img: np.ndarray, r: int) -> np.ndarray:
    return cv2.boxFilter(img, -1, (2 * r + 1, 2 * r + 1), normalize=True, borderType=cv2.BORDER_REFLECT)


def _magnitude_at(gx: np.ndarray, gy: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """The gradient's length at the flat indices `idx`. Not cv2.magnitude: with Intel IPP (in
    OpenCV's wheels) it rounds the last bit of ~a quarter of its results by where numpy put its
    output in memory, which changes from run to run (heap, threads), and so did the focus maps.
    Plain float32 products, sum and sqrt round the same way wherever the data lie."""
    u, v = gx.ravel().take(idx), gy.ravel().take(idx)
    return np.sqrt(u * u + v * v)


def guided_filter(guide: np.ndarray, src: np.ndarray, radius: int, eps: float) -> np.ndarray:
    """He et al. (2010) guided filter, grey guide, float32 inputs in [0, 1]. The same float32 operations
    as a = (box(I p) - box(I) box(p)) / (box(I I) - box(I)^2 + eps), b = box(p) - a box(I),
    box(a) I + box(b), done in place: one scratch image instead of a fresh one per operation."""
    mean_i = _box(guide, radius)
    mean_p = _box(src, radius)
    t = guide * src
    a = _box(t, radius)  # corr_ip
    np.multiply(guide, guide, out=t)
    var_i = _box(t, radius)
    var_i -= np.multiply(mean_i, mean_i, out=t)
    a -= np.multiply(mean_i, mean_p, out=t)
    var_i += eps
    a /= var_i
    b = mean_p
    b -= np.multiply(a, mean_i, out=t)
    out = _box(a, radius)
    out *= guide
    out += _box(b, radius)
    return out


class FocusEstimator:
    """`estimate(image_bgr) -> FocusResult` (thread-safe: no state between calls)."""

    def __init__(self, cfg: DetectorConfig) -> None:
        self.cfg = cfg

    def map_size(self, width: int, height: int) -> tuple[int, int]:
        mw = min(self.cfg.focus_map_width_px, width)
        return mw, max(1, int(round(height * mw / width)))

    def estimate(self, image_bgr: np.ndarray, person_mask: np.ndarray | None = None) -> FocusResult:
        """In-focus probability map of a frame. `person_mask` (bool, any resolution) keeps the
        propagation from mixing people with what is around them."""
        return self.propagate(self.measure_edges(image_bgr), person_mask)

    def measure_edges(self, image_bgr: np.ndarray) -> "EdgeEvidence":
        """Stage 1 (the expensive part, ~all the time): edges and their defocus sigma."""
        cfg = self.cfg
        h, w = image_bgr.shape[:2]
        grey = image_bgr if image_bgr.ndim == 2 else cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY)
        ww = min(cfg.focus_work_width_px, w)
        wh = max(1, int(round(h * ww / w)))
        if ww != w:
            grey = cv2.resize(grey, (ww, wh), interpolation=cv2.INTER_AREA)
        # A frame narrower than the work width: blur in its pixels is larger relative to its width.
        px_scale = ww / cfg.focus_work_width_px  # <= 1
        s0 = cfg.focus_reblur_sigma_px
        g = grey.astype(np.float32)
        g1 = cv2.GaussianBlur(g, (0, 0), s0)
        # central differences (same operator on both images, so its own blur cancels in the ratio)
        gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=1, scale=0.5)
        gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=1, scale=0.5)
        g1x = cv2.Sobel(g1, cv2.CV_32F, 1, 0, ksize=1, scale=0.5)
        g1y = cv2.Sobel(g1, cv2.CV_32F, 0, 1, ksize=1, scale=0.5)
        t = cfg.focus_edge_threshold
        # Canny's 3x3 Sobel magnitude is ~8x the central-difference gradient per pixel.
        # flat indices: one index array instead of two (a third of the pixels are edges); found in a
        # boolean image, whose nonzero numpy counts and finds ~5x faster than in Canny's uint8 0/255
        idx = np.flatnonzero(cv2.Canny(grey, 4.0 * t, 8.0 * t, L2gradient=True) > 0)
        mw, mh = self.map_size(w, h)
        guide = cv2.resize(grey, (mw, mh), interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0
        num = np.zeros((wh, ww), np.float32)
        den = np.zeros((wh, ww), np.float32)
        sigma = np.zeros(0, np.float32)
        if idx.size:
            m = _magnitude_at(gx, gy, idx)
            r = m / np.maximum(_magnitude_at(g1x, g1y, idx), 1e-6)
            r = np.maximum(r, 1.0 + 1e-3)
            sigma = np.minimum(s0 / np.sqrt(r * r - 1.0), 50.0).astype(np.float32)
            wgt = np.minimum(m / (4.0 * t), 4.0)  # contrast weight, saturating
            num.ravel()[idx] = np.log(sigma) * wgt
            den.ravel()[idx] = wgt
        # mean-pool to the map resolution (both alike; the ratio is what counts)
        num = cv2.resize(num, (mw, mh), interpolation=cv2.INTER_AREA)
        den = cv2.resize(den, (mw, mh), interpolation=cv2.INTER_AREA)
        return EdgeEvidence(num=num, den=den, guide=guide, sigma_edges=sigma, work_width=ww,
                            px_scale=px_scale, frame_width=w)

    def propagate(self, ev: "EdgeEvidence", person_mask: np.ndarray | None = None) -> FocusResult:
        """Stage 2 (cheap, map resolution): sparse log-sigma -> dense in-focus probability."""
        cfg = self.cfg
        mh, mw = ev.num.shape
        thr = cfg.focus_sigma_threshold_px * ev.px_scale
        soft = cfg.focus_sigma_softness_px * ev.px_scale
        s = max(0.5, cfg.focus_propagation_sigma_px * mw / ev.work_width)
        # edge density that counts as enough evidence: about one unit-weight edge pixel per
        # (2 x propagation sigma)^2 work pixels
        eps = np.float32(1.0 / (2.0 * cfg.focus_propagation_sigma_px) ** 2)

        def spread(num: np.ndarray, den: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return cv2.GaussianBlur(num, (0, 0), s), cv2.GaussianBlur(den, (0, 0), s)

        if person_mask is not None and person_mask.any():
            m = cv2.resize(person_mask.astype(np.float32), (mw, mh), interpolation=cv2.INTER_AREA)
            inside = m >= 0.5
            mi = inside.astype(np.float32)
            n_in, d_in = spread(ev.num * mi, ev.den * mi)
            n_out, d_out = spread(ev.num * (1 - mi), ev.den * (1 - mi))
            # renormalise by the share of the kernel that falls on each side
            c_in, c_out = spread(mi, 1 - mi)
            n_in, d_in = n_in / np.maximum(c_in, 1e-3), d_in / np.maximum(c_in, 1e-3)
            n_out, d_out = n_out / np.maximum(c_out, 1e-3), d_out / np.maximum(c_out, 1e-3)
            num = np.where(inside, n_in, n_out)
            den = np.where(inside, d_in, d_out)
        else:
            inside = None
            num, den = spread(ev.num, ev.den)
        log_sigma = num / np.maximum(den, 1e-12)
        conf = den / (den + eps)
        z = np.clip((np.log(thr) - log_sigma) / (soft / thr), -30.0, 30.0)  # soft is in px near thr
        p_edge = 1.0 / (1.0 + np.exp(-z))
        dense = (conf * p_edge + (1.0 - conf) * cfg.focus_no_edge_prior).astype(np.float32)
        rad = max(1, int(round(2 * mw / 160)))
        if inside is None:
            dense = guided_filter(ev.guide, dense, rad, 1e-3)
        else:  # filter each side on its own, then recombine
            a = guided_filter(ev.guide, np.where(inside, dense, 0).astype(np.float32), rad, 1e-3)
            b = guided_filter(ev.guide, np.where(inside, 0, dense).astype(np.float32), rad, 1e-3)
            ca = _box(inside.astype(np.float32), rad)
            dense = np.where(inside, a / np.maximum(ca, 1e-3), b / np.maximum(1 - ca, 1e-3))
        return FocusResult(np.clip(dense, 0.0, 1.0).astype(np.float32), ev.sigma_edges, mw / ev.frame_width)


@dataclass(frozen=True, eq=False)
class EdgeEvidence:
    """Stage-1 output of the focus estimator, at map resolution."""

    num: np.ndarray  # sum of weight * log(sigma) pooled per map pixel
    den: np.ndarray  # sum of weight pooled per map pixel
    guide: np.ndarray  # grey image at map resolution, [0, 1]
    sigma_edges: np.ndarray  # sigma at every edge pixel [work px]
    work_width: int
    px_scale: float
    frame_width: int
