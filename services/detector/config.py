"""Detector parameters: one frozen dataclass with documented defaults, units and ranges."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from cinetransfer.shared import nodeconfig
from cinetransfer.shared.camera_motion import ASSUMED_HFOV_DEG
from cinetransfer.shared.errors import ConfigError  # noqa: F401 (callers import it from here)
from cinetransfer.shared.nodeconfig import setting

BACKENDS = ("box_first", "mediapipe", "torchvision")
LANDMARK_MODELS = ("full", "heavy")
FALLBACKS = ("none", "hog")
RUNNING_MODES = ("video", "image")


@dataclass(frozen=True)
class DetectorConfig:
    """Everything that changes what or how fast the detector measures.

    Pose (people, masks, skeletons):
    """

    backend: str = setting("box_first", flag="--backend", choices=BACKENDS, help="pose backend")
    #                             'box_first' (SSD boxes, then landmarks per box; models from npm at install),
    #                             'mediapipe' (face-anchored landmarker from the wheel) or 'torchvision' (user weights)
    # --- box_first backend (box_first.py): if its models are not installed it reports itself
    #     unavailable and the detector runs the mediapipe backend instead
    bf_landmark_model: str = setting("full", flag="--landmark-model", choices=LANDMARK_MODELS,
                                     help="box_first: landmark model per person box: 'full' (~12 ms/person) "
                                          "or 'heavy' (~40 ms/person)")
    bf_score_threshold: float = 0.35  # SSD Person score threshold, (0, 1) (scores are compressed: 0.5 misses most)
    bf_score_full: float = 0.55  # SSD score that counts as a certain person (confidence scale), > bf_score_threshold
    bf_nms_iou: float = 0.5  # SSD boxes overlapping more than this (IoU) are one, (0, 1]
    bf_crop_scale: float = 1.25  # landmark crop side / the box's long side, 1..3
    bf_min_pose_flag: float = 0.1  # landmark model's "a pose is here" score below which a box is dropped, [0, 1]
    bf_track_min_pose_flag: float = 0.5  # ... for a person followed by landmarks alone (detector lost it), [0, 1]
    bf_track_confidence: float = 0.5  # confidence of such a person = this x the pose flag, [0, 1]
    bf_max_coast_frames: int = 30  # follow a person by landmarks alone for at most this many frames, 0..1000
    bf_mask_box_min_iou: float = 0.6  # use the mask's box when it overlaps the SSD box this much, [0, 1]
    bf_mask_box_weight: float = 1.0  # reported box = w x mask box + (1 - w) x SSD box, when they agree, [0, 1]
    bf_max_people: int = 12  # most people reported per frame, 1..50
    bf_track_iou: float = 0.3  # a person overlapping one of the previous frame this much keeps its track id, (0, 1]
    bf_threads: int = 1  # LiteRT threads per model (the other core runs the focus map), 1..4
    # threads 2: the SSD and a person's second landmark crop run in a worker thread beside the caller's crop.
    # Off, they run in the caller's thread after it (the same measurements): a stream's pose and tail
    # threads still overlap, and a frame costs ~2 ms CPU less on two busy cores (the output's measuring)
    bf_pose_worker: bool = True
    # video mode: the SSD runs on every Nth frame only while each person of the last frame (at most
    # bf_ssd_skip_max_people of them: in a crowd people come and go) was confirmed by it, is followed by its
    # landmarks again (pose flag >= bf_track_min_pose_flag) and no one is missing; between, a person's box is
    # its mask's box carried by the last SSD box's offset from it. 1 = every frame. A person entering the
    # frame is found at most N - 1 frames late (9 at 10: 0.375 s at 24 frames/s)
    bf_ssd_every: int = setting(10, flag="--ssd-every", range="[1, 10]", metavar="N",
                                help="box_first, video mode: run the person-box SSD every Nth frame while "
                                     "everyone is followed by landmarks (1 = every frame)")
    bf_ssd_skip_max_people: int = 2  # ... only while at most this many people are followed, 1..50
    # --- mediapipe backend
    num_poses: int = setting(6, flag="--num-poses", range="[1, 20]", help="max people per frame")
    min_detection_confidence: float = 0.3  # person-detector score threshold, [0, 1]
    min_presence_confidence: float = 0.3  # landmark presence threshold to keep a tracked pose, [0, 1]
    min_tracking_confidence: float = 0.3  # tracking threshold (video mode), [0, 1]
    running_mode: str = setting("video", flag="--running-mode", choices=RUNNING_MODES,
                                help="mediapipe mode: 'video' tracks over frames (needs increasing stamps)")
    upscale_max_side_px: int = setting(0, flag="--upscale", unit="px", metavar="PX",
                                       help="run pose on the frame upscaled to this long side, for small "
                                            "people (0 = off)")
    tiles: int = setting(0, flag="--tiles", range="[0, 4]",
                         help="extra pose pass over N overlapping vertical tiles (small, far people); 0 = off")
    mask_threshold: float = 0.5  # segmentation probability that counts as person, (0, 1)
    # masks snapped to image edges within this radius, cut to the pieces holding the person's joints
    mask_refine_radius_px: int = 3  # (subject_mask.py) [px], 0 = off, 0..20
    min_person_confidence: float = 0.35  # drop people whose derived confidence is below this, [0, 1]
    dedup_iou: float = 0.5  # two detections whose boxes overlap more than this are one person, (0, 1]
    # a box nested in another (this fraction of it inside) is the same person when the body agrees (dedupe.py):
    dedup_inside: float = 0.8  # fraction of the smaller box inside the larger, (0, 1]
    dedup_joint_dist: float = 0.1  # median joint distance / the nested box's height, [0, 1]
    dedup_mask_inside: float = 0.8  # ... or fraction of its mask inside the other's mask, (0, 1]
    min_box_height_px: int = 8  # ignore people smaller than this [px]
    # --- fallback person detector (any backend): finds people the pose model misses (back views,
    #     crowds) as box-only detections; costs ~50-90 ms/frame on one core, so off by default
    person_fallback: str = setting("none", flag="--fallback", choices=FALLBACKS,
                                   help="extra person detector for people the pose model misses "
                                        "('hog': OpenCV's HOG pedestrian detector)")
    hog_work_height_px: int = 384  # frames are downscaled to this height for HOG [px]
    hog_min_score: float = 0.0  # HOG SVM margin threshold (higher = fewer, surer boxes)
    hog_box_shrink_xy: tuple[float, float] = (0.5, 0.8)  # HOG window -> person box, about its centre
    fallback_overlap: float = 0.3  # a fallback box overlapping a pose person this much (IoU) is dropped
    # --- torchvision backend (user-supplied checkpoints; see torchvision_backend.py)
    tv_mask_checkpoint: str = setting("", flag="--mask-checkpoint", metavar="FILE",
                                      help="torchvision Mask R-CNN state_dict (backend torchvision; '' = none)")
    tv_keypoint_checkpoint: str = setting("", flag="--keypoint-checkpoint", metavar="FILE",
                                          help="torchvision Keypoint R-CNN state_dict (backend torchvision)")
    tv_mask_arch: str = "maskrcnn_resnet50_fpn"  # or 'maskrcnn_resnet50_fpn_v2'
    tv_keypoint_arch: str = "keypointrcnn_resnet50_fpn"
    tv_person_label: int = 1  # class index of 'person' in the checkpoint (COCO: 1)
    tv_score_threshold: float = 0.5  # keep detections scoring at least this, [0, 1]
    tv_min_size_px: int = 800  # torchvision's resize (short side) [px]
    tv_max_size_px: int = 1333  # torchvision's resize (long side cap) [px]
    tv_device: str = setting("cpu", flag="--device", help="torch device for the torchvision backend")
    # --- focus (Zhuo & Sim 2011 edge-based defocus; no weights)
    focus: bool = setting(True, flag="--no-focus", help="skip the focus map")
    focus_work_width_px: int = setting(640, flag="--focus-width", unit="px", range="[32, 4096]", metavar="PX",
                                       help="focus estimator working width (frames are downscaled to it)")
    focus_map_width_px: int = 160  # width of the published focus map [px] (height keeps the aspect)
    focus_reblur_sigma_px: float = 1.0  # re-blur Gaussian sigma sigma0 [work px]
    focus_sigma_threshold_px: float = 1.0  # defocus sigma at which P(in focus) = 0.5 [work px]
    focus_sigma_softness_px: float = 0.35  # logistic width of that transition [work px]
    focus_edge_threshold: float = 8.0  # min gradient magnitude for an edge pixel [grey levels/px]
    focus_propagation_sigma_px: float = 10.0  # spatial scale of sparse-to-dense propagation [work px]
    focus_no_edge_prior: float = 0.3  # P(in focus) where no edge is near (flat or very blurred areas)
    # --- camera motion (camera_motion.py): background corners tracked between consecutive frames
    camera_motion: bool = setting(True, flag="--no-camera-motion", help="skip the camera-motion measure")
    camera_hfov_deg: float = setting(ASSUMED_HFOV_DEG, flag="--camera-hfov", unit="deg", range="[5, 150]",
                                     metavar="DEG", help="horizontal field of view assumed for a frame whose "
                                                         "lens is unknown (rotation rates scale with it)")
    # tracks on a straight edge that slide along it over the parallax baseline (shared/camera_motion.py
    # sliding_edges) judged by their motion across it only and left out of the translation fit; every
    # other edge track counts as a corner (docs/camera_motion.md, "Edge tracks, judged across their edge")
    camera_motion_edge_tracks: bool = True
    # --- execution
    threads: int = setting(2, flag="--threads", choices=(1, 2),
                           help="1 = sequential; 2 = focus and pose in parallel (uses both cores)")

    # OpenCV's own worker threads (process-wide, set when a Detector is made; 0 = leave OpenCV's default).
    # The detector already spreads its stages over both cores; OpenCV splitting each call over them as
    # well costs ~10 % more CPU a frame at 1280x720 (benchmarks/detector.py) for no gain
    cv_threads: int = 1  # 0..8
    # glibc's malloc keeps freed blocks of up to 32 MB for reuse instead of returning them to the kernel
    # (process-wide, set when a Detector is made; allocator.py): a frame's arrays then cost no page faults.
    # Off: the default stream paid few faults anyway, and the README command's peak memory rose 786 -> 944 MB
    keep_freed_memory: bool = False

    def validate(self) -> "DetectorConfig":
        def need(cond: bool, name: str, allowed: str) -> None:
            if not cond:
                raise ConfigError(f"detector config: {name}={getattr(self, name)!r} is invalid; allowed: {allowed}")

        need(self.backend in BACKENDS, "backend", " | ".join(BACKENDS))
        need(self.person_fallback in FALLBACKS, "person_fallback", " | ".join(FALLBACKS))
        need(64 <= self.hog_work_height_px <= 2160, "hog_work_height_px", "64..2160")
        need(len(self.hog_box_shrink_xy) == 2 and all(0.1 <= v <= 1.0 for v in self.hog_box_shrink_xy),
             "hog_box_shrink_xy", "two values in 0.1..1")
        need(0.0 <= self.fallback_overlap <= 1.0, "fallback_overlap", "[0, 1]")
        need(self.bf_landmark_model in LANDMARK_MODELS, "bf_landmark_model", " | ".join(LANDMARK_MODELS))
        need(0.0 < self.bf_score_threshold < 1.0, "bf_score_threshold", "(0, 1)")
        need(self.bf_score_threshold < self.bf_score_full <= 1.0, "bf_score_full", "(bf_score_threshold, 1]")
        need(0.0 < self.bf_nms_iou <= 1.0, "bf_nms_iou", "(0, 1]")
        need(1.0 <= self.bf_crop_scale <= 3.0, "bf_crop_scale", "1..3")
        need(0.0 <= self.bf_min_pose_flag <= 1.0, "bf_min_pose_flag", "[0, 1]")
        need(0.0 <= self.bf_track_min_pose_flag <= 1.0, "bf_track_min_pose_flag", "[0, 1]")
        need(0.0 <= self.bf_track_confidence <= 1.0, "bf_track_confidence", "[0, 1]")
        need(0 <= self.bf_max_coast_frames <= 1000, "bf_max_coast_frames", "0..1000")
        need(0.0 <= self.bf_mask_box_weight <= 1.0, "bf_mask_box_weight", "[0, 1]")
        need(0.0 <= self.bf_mask_box_min_iou <= 1.0, "bf_mask_box_min_iou", "[0, 1]")
        need(1 <= self.bf_max_people <= 50, "bf_max_people", "1..50")
        need(0.0 < self.bf_track_iou <= 1.0, "bf_track_iou", "(0, 1]")
        need(1 <= self.bf_threads <= 4, "bf_threads", "1..4")
        need(1 <= self.bf_ssd_every <= 10, "bf_ssd_every", "1..10")
        need(1 <= self.bf_ssd_skip_max_people <= 50, "bf_ssd_skip_max_people", "1..50")
        need(self.running_mode in RUNNING_MODES, "running_mode", " | ".join(RUNNING_MODES))
        need(1 <= self.num_poses <= 20, "num_poses", "1..20")
        for name in ("min_detection_confidence", "min_presence_confidence", "min_tracking_confidence",
                     "min_person_confidence", "tv_score_threshold", "focus_no_edge_prior"):
            need(0.0 <= getattr(self, name) <= 1.0, name, "[0, 1]")
        need(0.0 < self.mask_threshold < 1.0, "mask_threshold", "(0, 1)")
        need(0 <= self.mask_refine_radius_px <= 20, "mask_refine_radius_px", "0..20")
        need(5.0 <= self.camera_hfov_deg <= 150.0, "camera_hfov_deg", "[5, 150]")
        need(0.0 < self.dedup_iou <= 1.0, "dedup_iou", "(0, 1]")
        need(0.0 < self.dedup_inside <= 1.0, "dedup_inside", "(0, 1]")
        need(0.0 <= self.dedup_joint_dist <= 1.0, "dedup_joint_dist", "[0, 1]")
        need(0.0 < self.dedup_mask_inside <= 1.0, "dedup_mask_inside", "(0, 1]")
        need(self.upscale_max_side_px == 0 or 64 <= self.upscale_max_side_px <= 4096, "upscale_max_side_px",
             "0 or 64..4096")
        need(0 <= self.tiles <= 4, "tiles", "0..4")
        need(self.min_box_height_px >= 0, "min_box_height_px", ">= 0")
        need(self.tv_min_size_px >= 32 and self.tv_max_size_px >= self.tv_min_size_px, "tv_min_size_px",
             ">= 32 and <= tv_max_size_px")
        need(self.tv_person_label >= 1, "tv_person_label", ">= 1")
        need(32 <= self.focus_work_width_px <= 4096, "focus_work_width_px", "32..4096")
        need(8 <= self.focus_map_width_px <= self.focus_work_width_px, "focus_map_width_px",
             "8..focus_work_width_px")
        need(0.3 <= self.focus_reblur_sigma_px <= 5.0, "focus_reblur_sigma_px", "0.3..5")
        need(0.1 <= self.focus_sigma_threshold_px <= 20.0, "focus_sigma_threshold_px", "0.1..20")
        need(0.01 <= self.focus_sigma_softness_px <= 10.0, "focus_sigma_softness_px", "0.01..10")
        need(0.0 < self.focus_edge_threshold <= 255.0, "focus_edge_threshold", "(0, 255]")
        need(1.0 <= self.focus_propagation_sigma_px <= 200.0, "focus_propagation_sigma_px", "1..200")
        need(self.threads in (1, 2), "threads", "1 | 2")
        need(0 <= self.cv_threads <= 8, "cv_threads", "0..8")
        if self.backend == "torchvision":
            need(bool(self.tv_mask_checkpoint or self.tv_keypoint_checkpoint), "tv_mask_checkpoint",
                 "a checkpoint path (or tv_keypoint_checkpoint) when backend='torchvision'")
        return self

    def replace(self, **changes: Any) -> "DetectorConfig":
        return dataclasses.replace(self, **changes).validate()


def add_config_arguments(parser: Any) -> None:
    """The detector's flags: its config fields that name one (shared/nodeconfig.py)."""
    nodeconfig.add_settings_arguments(parser, DetectorConfig, "detector")


def config_from_args(args: Any) -> DetectorConfig:
    """The code defaults, then the node's settings (if the parser has --config), then the flags given."""
    return nodeconfig.config_from_args(DetectorConfig, args, "detector")
