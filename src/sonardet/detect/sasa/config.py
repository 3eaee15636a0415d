"""Hyper-parameters of the SASA detector: ``DEFAULTS`` (the 2-core CPU budget) and ``STUDY`` (the study).

Every key is flat (one level) so it maps one-to-one onto the workflow config schema; units are in the
key names (``_m`` metres, ``_rad`` radians) or stated below. ``resolve_params`` fills defaults and
validates; ``describe_difference`` names the first setting in which two parameter sets differ (used
to refuse a checkpoint trained with another config).

Why these numbers (sonar scenes, not KITTI)
-------------------------------------------
Data: 40 m x 40 m MBES scenes, ~180 soundings/m^2 on the seabed (300k-600k points), ~55 reef
elements 0.75-2.1 m tall and 2-2.7 m wide (reef_ring 2.7 x 2.7 x 0.75-0.9 m, reef_cone 2.0 x 2.0 x
1.4 m, tetrapod_b 2.3 x 2.5 x 2.1 m, tetrapod_s 1.6 x 1.7 x 1.5 m), seabed near -11.5 m.

* **Ground filter** (``ground_cell_m`` 2 m, ``ground_height_m`` 0.2 m): the seabed is ~90 % of the
  soundings and carries no object. The minimum z per 2 m cell, bilinearly interpolated between cell
  centres, is a cheap ground estimate (2 m is smaller than every footprint, so MBES soundings between
  legs/holes still reach the seabed in almost every cell; seabed slope <= 3 deg changes z by <= 0.1 m
  over a cell). Keeping points > 0.2 m above it keeps 45k (28k-73k) of ~300k points per scene and
  >= 76 % of every object's soundings (median 89-100 % per class; measured on 24 scenes), and drops
  > 95 % of the seabed. The same estimate gives the per-point input feature "height above ground" (m).
* **Input size** (``n_points`` 8192): a random sample of the kept points (~18 % of them): ~100 points
  per object on average, >= 25 for a poorly seen small tetrapod (>= 150 soundings for 95 % of them).
  The KITTI 16384 is the STUDY value (twice the cost of every layer).
* **Radii** (dilated shells, as the reference): after the ground filter the sampled points lie on
  ~450 m^2 of object/rock surface, i.e. ~18 points/m^2 (spacing ~0.24 m) for 8192 points. SA1 keeps
  2048 D-FPS centres (~4.5/m^2, spacing ~0.5 m) and groups shells [0-0.3, 0.3-0.6, 0.6-1.0] m with
  [8, 16, 16] samples (expected hits ~5 / 15 / 35 on a surface: the inner shells are about filled,
  the outer one is subsampled). SA2 (1024 centres out of 2048 points, ~4.5 points/m^2) uses
  [0-0.6, 0.6-1.0, 1.0-1.6] m (hits ~5 / 9 / 22), SA3 (512 centres out of 1024 points)
  [0-1.0, 1.0-1.6, 1.6-2.4] m, both with [8, 16, 16]: SA3's outer shell spans a whole element (the
  largest half-diagonal is ~1.5 m) plus its neighbours. KITTI's 0.2/0.4/0.8 m at 16384 points over a
  70 m x 80 m range would see ~1 neighbour per ball here (see reference/sasa.md section 11).
* **Sampling counts**: 55 objects per scene; the candidates are the 256 S-FPS points of SA3, i.e.
  ~4-5 per object when the segmentation branch is good (S-FPS spreads them over the foreground).
  SA2 = 512 S-FPS + 512 D-FPS, SA3 = 256 S-FPS (from the S-FPS half) + 256 D-FPS (from the D-FPS
  half), the reference pattern with halved counts (our objects are 2x smaller, but 3-5x more
  numerous, than cars in a KITTI frame, and the cloud is 2x smaller).
* **Vote head**: offsets clamped to [1.5, 1.5, 1.0] m (a surface point is at most ~1.3 m in x/y and
  ~1.1 m in z from its box centre); votes group the 512 SA3 points inside 1.0 m (the element itself)
  and 2.0 m (element + contact neighbours) with 16 / 16 samples. A vote is a positive if it lies in a
  gt box and within ``gt_central_radius_m`` 1.5 m of its centre (KITTI: 10 m, i.e. anywhere in a car).
* **Widths and sample counts**: about half the KITTI widths and nsample 8/16/16 instead of 32/32/64
  (CPU budget: the last, widest shell of every layer dominated the cost; these settings cut a
  training step at batch 4 from ~3.2 s to ~1.7 s on one core, ~1.0 s on two quiet cores). The
  scenes hold 4 classes of rigid shapes that differ mostly in size and height; STUDY uses the KITTI
  widths.
* **Yaw**: the rings and cones are rotationally symmetric (``symmetry_orders`` 0: yaw is not
  predicted, the box is axis aligned, angle losses are masked); a tetrapod repeats every 120 deg
  (order 3), so the coder bins the folded angle 3*yaw (12 bins over 2 pi) and decodes yaw in
  [-pi/3, pi/3), the convention of the scene boxes.
* **Augmentation**: rotation U(-pi, pi) and flips about x and y (no preferred heading on the seabed);
  scaling only U(0.97, 1.03): tetrapod_s and tetrapod_b differ by a factor 1.46 in size, the narrow
  range keeps the two size classes apart. Per-object jitter moves an element's points by
  N(0, 0.2 m) in x/y and turns them about the box centre (never bringing two elements closer than
  they were unless they stay clear of each other).
* **NMS**: 19 % of the elements are stacked or interlocked with another whose BEV IoU exceeds 0.25
  (up to 0.7, rings stacked on rings), while their 3-D IoU stays <= 0.4. Greedy NMS therefore uses
  the rotated BEV overlap of the ops module times the vertical overlap (3-D IoU, ``nms_mode`` "3d");
  the threshold 0.5 was the best of 0.1-0.75 on validation scenes drawn from the training split
  (0.25: -0.03 mAP, 0.75: duplicates); never on test scenes. "bev" (the reference's rotated BEV IoU NMS) is available; 0.01 (KITTI) would
  suppress touching elements.
* **Optimisation**: Adam + decoupled weight decay 0.01 with the one-cycle schedule of the reference;
  max LR scaled linearly from 0.01 at batch 8 to 0.005 at batch 4. **Epochs: chosen on the
  development scenes**, not fixed: the dev mAP is measured every ``val_every_epochs`` (2) epochs, the
  best model is kept, and training stops after ``early_stop_patience`` (3) evaluations without a
  dev mAP better by ``early_stop_min_delta``, at the latest after ``epochs`` (40, the cap, which also
  sets the length of the one-cycle schedule), but not before ``early_stop_min_epoch_frac`` of the
  cap, which is 1.0 by default: every training runs to the cap and keeps its best dev checkpoint.
  With the one-cycle schedule the dev mAP swings by ~0.1 between evaluations until the LR anneals:
  a stop allowed from epoch 0 cut the default run's 50 % and domain-randomised trainings at 26 and
  24 of 40 epochs (dev mAP 0.78 and 0.82 against 0.93 for 100 % at 38); a stop allowed from 0.75 of
  the cap (30 epochs) cut the study-protocol run's 100 % training at 30, keeping epoch 24 (dev 0.971,
  while its 50 % training reached 0.996 at epoch 32 and stayed there). Patience and the fraction
  remain for schedules without annealing. The report plots the dev mAP against epochs for every
  fraction (figure dev_curves), so a reader sees whether training converged. (An earlier 20-epoch
  default had been read off a test mAP; the dev split replaced that choice.)
* **Domain randomisation** (``dr_*``, off by default: ``dr_enabled`` False runs the unchanged code
  path, no extra random draws). The simulator's soundings are a clean ray cast (1 cm range noise, exact
  attitude, no fliers); real MBES data are not (reference/mbes.md section 1.8). With ``dr_enabled``
  every training scene of every step gets its own sensor effects, drawn from the ranges below
  (uniform; counts uniform integers, both ends included; an effect is off with its range at [0, 0],
  ``dr_density_contrast`` at [1, 1] or ``dr_burial_prob`` at 0). They are applied in the local frame **after the ground filter** and before the
  augmentation, on the kept points of the scene (``data.domain_randomise``, called by
  ``trainer._make_batch``): re-running the ground filter on the raw 300k-600k soundings would cost
  ~30 ms per scene for the filter alone and would keep every raw cloud in memory; the effects the
  filter would have had are modelled instead (the height feature follows what the min-per-cell
  ground estimate would do; new seabed points appear where it would leak). Labels stay consistent:
  generated points (spikes, leaked seabed) are background (-1) and never fall inside a gt box
  footprint (+0.2 m); a smooth z distortion and a line offset move the boxes with the points at their
  centre; a sunk object's box sinks with it. Draws come from a generator derived from (``seed``,
  epoch, step), one child stream per effect, so training stays deterministic and resumable.
  Where the simulator has the effect, the model is the simulator's own, in its point-stage form
  (``sonardet.sim.effects``: burial, spikes, tilt and heave of the attitude, the SVP smile, line
  offsets, the sensor's float32 range noise, roughness); seabed leaks, dropout blobs and the density
  field have no sensor-model counterpart and live in ``data.py``.
  Ranges (physical reasoning, not fitted to any test set):

  - ``dr_range_noise_m`` [0, 0.03]: extra per-point vertical noise, sigma drawn per scene, added to
    z and to the height feature. Total vertical uncertainty of a 400 kHz MBES at 10-12 m is a few cm
    (Hare/CUBE error model: range, roll and SV terms); the simulator has 1 cm.
  - ``dr_tilt_deg`` [0, 0.5]: a planar tilt of the z field (random azimuth): an uncalibrated roll
    bias (the R2Sonic manual's example error is 0.5 deg; a patch test leaves <= 0.1 deg). The ground
    estimate follows a smooth field, so the height feature is unchanged; only z (and the box z) move.
  - ``dr_smile_coeff`` [-0.0073, 0.0073] with ``dr_smile_depth_m`` 11.5: refraction smile/frown
    k D (sqrt(1 + (u/D)^2) - 1) = k D (1/cos a - 1) across a virtual survey track at a random
    position and heading (u: across-track distance, clipped to the 65 deg swath edge); k = 0.0073 is
    1 % of the depth at 65 deg, the bias of modelled instead of measured sound-speed profiles.
  - ``dr_heave_m`` [0, 0.05], ``dr_heave_wavelength_m`` [8, 20]: residual heave, a sinusoid along
    the virtual track (kluster's heave 1 sigma is 5 cm; 4-10 s periods at 2 m/s).
  - ``dr_line_offset_m`` [0, 0.05], ``dr_line_spacing_m`` [10, 25], ``dr_line_overlap`` 0.5: virtual
    survey lines parallel to the track, each shifted vertically by N(0, sigma^2) (tide, draft,
    waterline residuals: kluster waterline 2 cm, RTK heights a few cm). In the overlap band around
    each strip boundary a point comes from either line (the doubled surfaces of real overlaps) and
    its height feature rises by its line's offset above the lower one (the min ground follows the
    lower surface). Line spacing: a 130 deg swath is 49 m wide at 11.5 m, 50-100 % overlap.
  - ``dr_roughness_m`` [0, 0.03]: isotropic N(0, sigma^2) displacement of object points
    (biofouling, mussel layers of a few cm, partly averaged by the 10-40 cm footprints).
  - ``dr_burial_prob`` 0.5, ``dr_burial_m`` [0, 0.3]: an object resting on the seabed sinks into
    the sediment (settlement and scour of 1-2 t concrete elements on sand over years); its points
    move down, those that end up below the ground-filter height vanish, its box moves down too
    (the box convention of the simulator's buried objects).
  - ``dr_outlier_frac`` [0, 0.01], ``dr_outlier_height_m`` [0.2, 2.0]: isolated spikes above the
    seabed (upward fliers, multibounce, side lobes): a share of the kept points, at random positions,
    height above the ground estimate drawn from the range (spikes of +-0.1-1 m along the beam, ghosts
    above the tallest element). The R2Sonic line had 0.24 % fliers > 0.3 m in its 50-60 deg band.
  - ``dr_leak_patches`` [0, 10], ``dr_leak_depth_m`` [0.1, 1.0]: seabed leaks through the ground
    filter. One deep (downward) flier lowers its cell's minimum by its depth d; the bilinear
    ground estimate then dips as a pyramid of half-width ``ground_cell_m`` around it, the height
    feature of every point there rises by up to d, and the seabed soundings whose height then
    exceeds ``ground_height_m`` are kept (generated here at the seabed density the filter removed).
    0 patches is cleaned data; 10 per 40 m x 40 m scene is ~6e-5 of 300k soundings being deep fliers.
  - ``dr_dropout_blobs`` [0, 6], ``dr_dropout_radius_m`` [0.3, 1.5]: missing data (specular walls,
    fish and bubble shadows, missing pings/beams): ellipses (semi-major axis from the range, aspect
    1-3, random heading) centred on random kept points (mostly on objects) lose all their points.
  - ``dr_density_contrast`` [1, 3]: a smooth sampling-density field (3 random waves of 8-40 m)
    with max/min ratio drawn from the range: equi-angular beams are ~4x sparser at 60 deg than at
    nadir, overlaps double the density, the vessel speed varies. (Only relative density matters: the
    ``n_points`` sample of a scene's kept points spans the same surfaces at any global density.)

  - ``dr_shape_prob`` (0, off: an option measured on dev, README "Objects unlike their models"),
    ``dr_shape_offset_frac`` 0.35, ``dr_shape_half_thickness_m`` (per class), ``dr_shape_fouling_m``
    [0, 0.05], ``dr_shape_wavelength_m`` [0.5, 2]: real elements are not their models (legs a third
    thinner or thicker, a fouling shell; the mismatch test set). With this probability an object's
    sampled points move along their surface normal (PCA of their 8 nearest points of the same object,
    turned to point up, toward the sensor: a near-nadir survey sees an object's outside from above)
    by a thickness offset U(-f, f) x the class's half thickness (tetrapod leg radius, half a wall:
    measured on the meshes, ``models.ClassModel.half_thickness_m``; a plugin's class needs its value
    here before the effect is switched on), plus a fouling shell U(range)
    thick, uneven (times 0.5 + 0.5 sin of a random plane wave of the wavelength range). Points whose
    normal is nearly horizontal (|n_z| < 0.2, a wall seen from the side: which side is outside is
    unknown without the sensor position) move by the shell only. Boxes stay (the label is the
    object, not its model), the height feature moves with z.

  With the other effects the ``n_points`` sample is drawn with these weights (without replacement).
  Cost, measured on real training scenes (286k soundings, 26k-34k kept; batch 4, one busy core):
  ``_make_batch`` takes ~11 ms per step without and ~55 ms with domain randomisation (~11 ms per
  scene), against 1.3-2.7 s for the whole step (< 4 %); the ground filter alone on the 4 raw
  clouds would have added ~130 ms per step.
"""

from __future__ import annotations

import copy
import math

__all__ = ["DEFAULTS", "PRESETS", "STUDY", "RUNTIME_KEYS", "INFERENCE_KEYS", "ARCHITECTURE_KEYS", "resolve_params",
           "describe_difference", "model_settings", "architecture_settings"]

CLASSES = ["reef_ring", "reef_cone", "tetrapod_b", "tetrapod_s"]

#: Default CPU budget (2 cores). See the module docstring for the reasoning, the report for units.
DEFAULTS: dict = {
    # ---- data ----
    "classes": list(CLASSES),                # class names, order = logit order
    "symmetry_orders": {"reef_ring": 0, "reef_cone": 0, "tetrapod_b": 3, "tetrapod_s": 3},  # 0 = yaw-free
    "ground_filter": True,                   # drop points near the grid-minimum ground before sampling
    "ground_cell_m": 2.0,                    # cell size of the ground estimate (m)
    "ground_height_m": 0.2,                  # keep points higher than this above the ground (m)
    "point_feature": "height",               # extra input channel: "height" above the ground estimate or "none" (0)
    "n_points": 8192,                        # input points per scene after the ground filter
    # ---- backbone (3 SA layers: D-FPS; S-FPS + D-FPS; S-FPS + D-FPS) ----
    "sa_npoints": [2048, 1024, 512],         # centres per layer (layers 2, 3: half S-FPS, half D-FPS)
    "sa_radii_m": [[0.3, 0.6, 1.0], [0.6, 1.0, 1.6], [1.0, 1.6, 2.4]],  # shell outer radii (m)
    "sa_nsamples": [[8, 16, 16], [8, 16, 16], [8, 16, 16]],           # neighbours per shell
    "sa_mlps": [[[16, 16, 32], [16, 16, 32], [16, 32, 32]],
                [[32, 32, 64], [32, 32, 64], [32, 48, 64]],
                [[64, 64, 96], [64, 64, 96], [64, 96, 128]]],          # shared MLP widths per shell
    "sa_aggregation": [64, 128, 128],        # aggregation width per layer
    "sa_confidence_mlps": [[32], [64]],      # segmentation branch widths after SA1, SA2
    "dilated_groups": True,                  # shells r_{i-1} <= d < r_i instead of balls
    "sfps_gamma": 1.0,                       # S-FPS weight exponent: w = sigmoid(logit)^gamma
    # ---- vote head ----
    "vote_mlp": [64],                        # vote layer widths
    "vote_range_m": [1.5, 1.5, 1.0],         # max |offset| per axis (m)
    "vote_radii_m": [1.0, 2.0],              # grouping radii around votes (m), balls
    "vote_nsamples": [16, 16],               # neighbours per vote radius
    "vote_mlps": [[128, 128], [128, 256]],   # vote SA MLP widths per radius
    "head_shared_fc": [256, 128],            # shared FC widths after the vote SA
    "head_cls_fc": [128],                    # classification branch widths
    "head_reg_fc": [128],                    # regression branch widths
    "angle_bins": 12,                        # yaw bins over the folded angle
    # ---- targets and losses ----
    "vote_extra_width_m": 0.2,               # candidates inside gt box + this (total, m) get vote targets
    "gt_central_radius_m": 1.5,              # votes farther from the centre (inside the box) are ignored
    "seg_extra_width_m": 0.4,                # ignore band of the segmentation labels (total, m)
    "seg_layer_weights": [0.01, 0.1],        # SASA segmentation loss weights for SA1, SA2
    "loss_vote": 1.0,                        # weight of the vote loss
    "loss_cls": 1.0,                         # weight of the classification loss (BCE summed over classes)
    "loss_reg": 1.0,                         # weight of the centre/size smooth-L1 loss
    "loss_dir_cls": 0.2,                     # weight of the yaw-bin cross entropy
    "loss_dir_res": 1.0,                     # weight of the yaw residual smooth-L1
    "loss_corner": 1.0,                      # weight of the symmetry-aware corner loss
    "loss_iou": 1.0,                         # weight of the axis-aligned 3-D IoU loss
    # ---- training ----
    "seed": 20260101,                        # base seed (model init, data order, augmentation)
    "batch_size": 4,                         # scenes per step
    "epochs": 40,                            # the cap on passes over the training scenes (early stopping on dev)
    "lr": 0.005,                             # one-cycle max learning rate
    "weight_decay": 0.01,                    # decoupled (AdamW) weight decay
    "pct_start": 0.4,                        # share of steps with rising LR
    "div_factor": 10.0,                      # initial LR = lr / div_factor
    "final_div_factor": 1.0e4,               # final LR = initial LR / final_div_factor
    "moms": [0.95, 0.85],                    # beta1 range of the one-cycle momentum
    "grad_clip": 10.0,                       # gradient norm clip
    "aug_rotation_rad": math.pi,             # world rotation U(-a, a) about z (rad)
    "aug_flip_x": True,                      # random mirror y -> -y
    "aug_flip_y": True,                      # random mirror x -> -x
    "aug_scale": [0.97, 1.03],               # world scaling range
    "aug_object_prob": 0.5,                  # per-object jitter probability
    "aug_object_sigma_m": 0.2,               # per-object translation sigma in x, y (m)
    "aug_object_rotation_rad": math.pi,      # per-object rotation U(-a, a) about its box centre (rad)
    "val_every_epochs": 2,                   # dev mAP every n epochs (0: only at the end); the best one is kept
    "early_stop_patience": 3,                # stop after this many dev evaluations without a better mAP (0: never)
    "early_stop_min_delta": 0.002,           # an evaluation is better if its dev mAP exceeds the best by this
    "early_stop_min_epoch_frac": 1.0,        # no early stop before this share of the cap (1: train to the cap)
    # ---- domain randomisation (training only; ranges [low, high] drawn uniformly per scene and step) ----
    "dr_enabled": False,                     # randomise sensor effects of every training scene (docstring)
    "dr_range_noise_m": [0.0, 0.03],         # sigma of extra vertical noise on z and height (m)
    "dr_tilt_deg": [0.0, 0.5],               # planar tilt of the z field, random azimuth (deg; roll bias)
    "dr_smile_coeff": [-0.0073, 0.0073],     # k of the smile k D (1/cos a - 1) across a virtual track (unitless)
    "dr_smile_depth_m": 11.5,                # D: transducer height above the seabed for the smile (m)
    "dr_heave_m": [0.0, 0.05],               # amplitude of a residual-heave wave along the track (m)
    "dr_heave_wavelength_m": [8.0, 20.0],    # its wavelength along the track (m)
    "dr_line_offset_m": [0.0, 0.05],         # sigma of the vertical offset of each virtual survey line (m)
    "dr_line_spacing_m": [10.0, 25.0],       # spacing of the virtual survey lines (m)
    "dr_line_overlap": 0.5,                  # share of a line strip whose points may come from a neighbour (0-1)
    "dr_roughness_m": [0.0, 0.03],           # sigma of the isotropic displacement of object points (m)
    "dr_burial_prob": 0.5,                   # chance that an object resting on the seabed is sunk
    "dr_burial_m": [0.0, 0.3],               # depth a sunk object goes down by (m)
    "dr_outlier_frac": [0.0, 0.01],          # spikes added, as a share of the scene's kept points
    "dr_outlier_height_m": [0.2, 2.0],       # height of a spike above the ground estimate (m)
    "dr_leak_patches": [0, 10],              # ground-estimate dips (deep fliers) letting seabed through (count)
    "dr_leak_depth_m": [0.1, 1.0],           # depth of such a dip (m)
    "dr_dropout_blobs": [0, 6],              # elliptic missing-data blobs per scene (count)
    "dr_dropout_radius_m": [0.3, 1.5],       # semi-major axis of a blob (m); aspect 1-3
    "dr_density_contrast": [1.0, 3.0],       # max/min ratio of a smooth sampling-density field (unitless, >= 1)
    "dr_shape_prob": 0.0,                    # share of objects whose seen surface is reshaped (0: off; docstring)
    "dr_shape_offset_frac": 0.35,            # thicker/thinner by up to this x the class half thickness
    "dr_shape_half_thickness_m": {"reef_ring": 0.045, "reef_cone": 0.075, "tetrapod_s": 0.31, "tetrapod_b": 0.44},
    "dr_shape_fouling_m": [0.0, 0.05],       # thickness of an uneven fouling shell on a reshaped object (m)
    "dr_shape_wavelength_m": [0.5, 2.0],     # wavelength of the shell's unevenness (m)
    # ---- inference ----
    "score_thresh": 0.1,                     # drop boxes below this score before NMS
    "nms_mode": "3d",                        # "3d" (rotated BEV x vertical overlap) or "bev"
    "nms_iou": 0.5,                          # NMS IoU threshold
    "nms_pre_max": 1024,                     # boxes entering NMS (top scores)
    "nms_post_max": 200,                     # boxes kept per scene
    # ---- runtime ----
    "num_threads": None,                     # torch CPU threads (None: leave torch's setting)
    "sampling_threads": 1,                   # CPU threads of the PyTorch FPS / ball query ops (0: num_threads;
                                             # the compiled kernels use num_threads, one per cloud)
    "compact_groups": True,                  # grouped MLPs on distinct hits only (False: padded, bitwise as before)
    "progress": True,                        # tqdm progress bar
    "retain_freed_memory": True,             # keep freed heap memory in the process (glibc; sonardet.allocator)
}

#: The study's SASA as published (blakechen97/SASA, OpenPCDet 3dssd_sasa KITTI config; reference/sasa.md):
#: the reference network (radii, nsample, widths, vote settings), 16384 points sampled from the RAW
#: scene (no ground filter: the seabed is in the input, as the study fed it; no extra channel, as we
#: simulate no intensity), 100 epochs, batch 8, AdamW one-cycle at 0.01, the reference augmentations
#: (flip in x, world rotation +-45 deg, scaling 0.9-1.1, per-box noise sigma 1 m and +-60 deg; the
#: reference's ground-truth sampling is not reproduced), rotated BEV NMS at 0.01, the last epoch kept.
STUDY: dict = copy.deepcopy(DEFAULTS)
STUDY.update({
    "ground_filter": False,
    "point_feature": "none",
    "n_points": 16384,
    "sa_npoints": [4096, 1024, 512],
    "sa_radii_m": [[0.2, 0.4, 0.8], [0.4, 0.8, 1.6], [1.6, 3.2, 4.8]],
    "sa_nsamples": [[32, 32, 64], [32, 32, 64], [32, 32, 64]],
    "sa_mlps": [[[16, 16, 32], [16, 16, 32], [32, 32, 64]],
                [[64, 64, 128], [64, 64, 128], [64, 96, 128]],
                [[128, 128, 256], [128, 196, 256], [128, 256, 256]]],
    "sa_aggregation": [64, 128, 256],
    "sa_confidence_mlps": [[32], [64]],
    "vote_mlp": [128],
    "vote_range_m": [3.0, 3.0, 2.0],
    "vote_radii_m": [4.8, 6.4],
    "vote_nsamples": [48, 64],
    "vote_mlps": [[256, 256, 512], [256, 512, 1024]],
    "head_shared_fc": [512, 256],
    "head_cls_fc": [128],
    "head_reg_fc": [128],
    "vote_extra_width_m": 0.1,
    "gt_central_radius_m": 10.0,
    "seg_extra_width_m": 1.0,
    "batch_size": 8,
    "epochs": 100,
    "lr": 0.01,
    "aug_rotation_rad": math.pi / 4,
    "aug_flip_x": True,
    "aug_flip_y": False,
    "aug_scale": [0.9, 1.1],
    "aug_object_prob": 0.5,
    "aug_object_sigma_m": 1.0,
    "aug_object_rotation_rad": math.pi / 3,
    "val_every_epochs": 10,
    "early_stop_patience": 0,
    "nms_mode": "bev",
    "nms_iou": 0.01,
    "nms_pre_max": 4096,
    "nms_post_max": 500,
})

#: Presets by name (config `sasa.preset`).
PRESETS = {"default": DEFAULTS, "study": STUDY}

#: Keys that do not change what is learned (not compared when resuming or loading a model).
RUNTIME_KEYS = frozenset({"num_threads", "sampling_threads", "compact_groups", "progress", "retain_freed_memory",
                          "val_every_epochs", "early_stop_patience", "early_stop_min_delta",
                          "early_stop_min_epoch_frac"})
#: Keys used only after the network (may differ between training and inference).
INFERENCE_KEYS = frozenset({"score_thresh", "nms_mode", "nms_iou", "nms_pre_max", "nms_post_max"})
#: Keys that define the network and its input: a model is only used with the values it was trained with.
ARCHITECTURE_KEYS = frozenset({
    "classes", "symmetry_orders", "ground_filter", "point_feature", "ground_cell_m", "ground_height_m", "n_points", "sa_npoints",
    "sa_radii_m", "sa_nsamples", "sa_mlps", "sa_aggregation", "sa_confidence_mlps", "dilated_groups", "sfps_gamma",
    "vote_mlp", "vote_range_m", "vote_radii_m", "vote_nsamples", "vote_mlps", "head_shared_fc", "head_cls_fc",
    "head_reg_fc", "angle_bins"})


def _check(cond: bool, key: str, msg: str) -> None:
    if not cond:
        raise ValueError(f"SASA parameter {key!r}: {msg}")


def resolve_params(params: dict | None = None, base: dict | None = None) -> dict:
    """Defaults (``base``, default ``DEFAULTS``) updated by ``params``; validated. Unknown keys raise."""
    base = DEFAULTS if base is None else base
    out = copy.deepcopy(base)
    for k, v in (params or {}).items():
        if k not in base:
            raise ValueError(f"unknown SASA parameter {k!r}; known: {', '.join(sorted(base))}")
        out[k] = copy.deepcopy(v)
    classes = out["classes"]
    _check(isinstance(classes, list) and len(classes) >= 1 and len(set(classes)) == len(classes),
           "classes", f"must be a non-empty list of distinct names, got {classes!r}")
    so = out["symmetry_orders"]
    for c in classes:
        _check(c in so and int(so[c]) >= 0, "symmetry_orders",
               f"needs an integer >= 0 for class {c!r} (0: rotationally symmetric, k: yaw period 2 pi / k)")
    _check(int(out["n_points"]) >= 16, "n_points", "must be >= 16")
    n = out["sa_npoints"]
    _check(len(n) == 3 and all(int(v) >= 2 for v in n), "sa_npoints", "three centre counts >= 2 expected")
    _check(n[1] % 2 == 0 and n[2] % 2 == 0, "sa_npoints", "layers 2 and 3 are half S-FPS, half D-FPS: use even counts")
    _check(n[2] // 2 <= n[1] // 2, "sa_npoints", "SA3 samples each half of SA2: sa_npoints[2] <= sa_npoints[1]")
    for key in ("sa_radii_m", "sa_nsamples", "sa_mlps"):
        _check(len(out[key]) == 3, key, "one entry per SA layer (3) expected")
    for li in range(3):
        r, s, m = out["sa_radii_m"][li], out["sa_nsamples"][li], out["sa_mlps"][li]
        _check(len(r) == len(s) == len(m) >= 1, "sa_radii_m",
               f"layer {li + 1}: radii, nsamples and mlps need the same length")
        _check(all(b > a for a, b in zip([0.0] + list(r), r)), "sa_radii_m",
               f"layer {li + 1}: radii must be positive and increasing, got {r}")
    _check(len(out["sa_aggregation"]) == 3, "sa_aggregation", "one width per layer expected")
    _check(len(out["sa_confidence_mlps"]) == 2, "sa_confidence_mlps", "branches after SA1 and SA2 expected")
    _check(len(out["seg_layer_weights"]) == 2, "seg_layer_weights", "weights for SA1 and SA2 expected")
    _check(len(out["vote_radii_m"]) == len(out["vote_nsamples"]) == len(out["vote_mlps"]) >= 1, "vote_radii_m",
           "vote radii, nsamples and mlps need the same length")
    _check(len(out["vote_range_m"]) == 3, "vote_range_m", "three values (x, y, z) expected")
    _check(int(out["angle_bins"]) >= 2, "angle_bins", "must be >= 2")
    _check(int(out["batch_size"]) >= 1, "batch_size", "must be >= 1")
    _check(int(out["epochs"]) >= 1, "epochs", "must be >= 1")
    _check(float(out["lr"]) > 0, "lr", "must be > 0")
    _check(out["nms_mode"] in ("3d", "bev"), "nms_mode", f"'3d' or 'bev', got {out['nms_mode']!r}")
    _check(out["point_feature"] in ("height", "none"), "point_feature", f"'height' or 'none', got {out['point_feature']!r}")
    _check(int(out["val_every_epochs"]) >= 0 and int(out["early_stop_patience"]) >= 0, "early_stop_patience",
           "val_every_epochs and early_stop_patience must be >= 0")
    _check(0.0 <= float(out["early_stop_min_epoch_frac"]) <= 1.0, "early_stop_min_epoch_frac", "must be in [0, 1]")
    lo, hi = out["aug_scale"]
    _check(0 < lo <= hi, "aug_scale", f"need 0 < low <= high, got {out['aug_scale']}")
    _check(float(out["ground_cell_m"]) > 0, "ground_cell_m", "must be > 0")
    _check(isinstance(out["dr_enabled"], bool), "dr_enabled", f"must be true or false, got {out['dr_enabled']!r}")
    for key, low, high, integer in _DR_RANGES:
        _check_range(out, key, low, high, integer)
    _check(float(out["dr_smile_depth_m"]) > 0, "dr_smile_depth_m", "must be > 0")
    _check(0.0 <= float(out["dr_line_overlap"]) <= 1.0, "dr_line_overlap", "must be in [0, 1]")
    _check(0.0 <= float(out["dr_burial_prob"]) <= 1.0, "dr_burial_prob", "must be in [0, 1]")
    _check(float(out["dr_line_spacing_m"][0]) > 0, "dr_line_spacing_m", "must be > 0")
    _check(0.0 <= float(out["dr_shape_prob"]) <= 1.0, "dr_shape_prob", "must be in [0, 1]")
    _check(0.0 <= float(out["dr_shape_offset_frac"]) < 1.0, "dr_shape_offset_frac",
           "must be in [0, 1): at 1 a thinner object would have no thickness left")
    ht = out["dr_shape_half_thickness_m"]
    _check(isinstance(ht, dict) and all(float(v) > 0 for v in ht.values()), "dr_shape_half_thickness_m",
           f"must map class names to half thicknesses > 0 (m), got {ht!r}")
    if float(out["dr_shape_prob"]) > 0:  # only the shape effect needs them (a plugin class may leave it off)
        missing = [c for c in classes if c not in ht]
        _check(not missing, "dr_shape_half_thickness_m",
               f"dr_shape_prob > 0 needs a half thickness (m) for every class; missing: {', '.join(missing)}")
    return out


#: (key, smallest allowed value, largest allowed value, integer) of the domain-randomisation ranges.
_DR_RANGES = (
    ("dr_range_noise_m", 0.0, None, False),
    ("dr_tilt_deg", 0.0, 45.0, False),
    ("dr_smile_coeff", None, None, False),
    ("dr_heave_m", 0.0, None, False),
    ("dr_heave_wavelength_m", 1e-6, None, False),
    ("dr_line_offset_m", 0.0, None, False),
    ("dr_line_spacing_m", 1e-6, None, False),
    ("dr_roughness_m", 0.0, None, False),
    ("dr_burial_m", 0.0, None, False),
    ("dr_outlier_frac", 0.0, 1.0, False),
    ("dr_outlier_height_m", 0.0, None, False),
    ("dr_leak_patches", 0, None, True),
    ("dr_leak_depth_m", 0.0, None, False),
    ("dr_dropout_blobs", 0, None, True),
    ("dr_dropout_radius_m", 0.0, None, False),
    ("dr_density_contrast", 1.0, None, False),
    ("dr_shape_fouling_m", 0.0, None, False),
    ("dr_shape_wavelength_m", 1e-3, None, False),
)


def _check_range(out: dict, key: str, low, high, integer: bool) -> None:
    v = out[key]
    ok = isinstance(v, (list, tuple)) and len(v) == 2 and all(
        isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)
    _check(ok, key, f"must be a range [low, high] of two numbers, got {v!r}")
    _check(v[0] <= v[1], key, f"need low <= high, got {v!r}")
    if integer:
        _check(all(float(x).is_integer() for x in v), key, f"must hold two integers, got {v!r}")
    if low is not None:
        _check(v[0] >= low, key, f"values must be >= {low}, got {v!r}")
    if high is not None:
        _check(v[1] <= high, key, f"values must be <= {high}, got {v!r}")


def model_settings(params: dict) -> dict:
    """The settings that define what a checkpoint learned (everything but runtime and inference keys)."""
    return {k: v for k, v in params.items() if k not in RUNTIME_KEYS and k not in INFERENCE_KEYS}


def architecture_settings(params: dict) -> dict:
    """The settings a trained model must be used with (network shape and input preparation)."""
    return {k: v for k, v in params.items() if k in ARCHITECTURE_KEYS}


def _norm(v):
    if isinstance(v, (list, tuple)):
        return [_norm(x) for x in v]
    if isinstance(v, dict):
        return {str(k): _norm(x) for k, x in sorted(v.items())}
    if isinstance(v, bool) or v is None or isinstance(v, str):
        return v
    if isinstance(v, (int, float)):
        return float(v)
    return v


def describe_difference(stored: dict, current: dict) -> str | None:
    """None if the two settings dicts agree, else a message naming the first differing key(s)."""
    diffs = []
    for k in sorted(set(stored) | set(current)):
        a, b = stored.get(k, "<absent>"), current.get(k, "<absent>")
        if _norm(a) != _norm(b):
            diffs.append(f"{k}: checkpoint {a!r} vs now {b!r}")
    if not diffs:
        return None
    more = f" (and {len(diffs) - 3} more)" if len(diffs) > 3 else ""
    return "; ".join(diffs[:3]) + more
