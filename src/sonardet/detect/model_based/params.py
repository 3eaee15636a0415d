"""Hyper-parameters of the model-based detector: `DEFAULTS` (variant `ours`) and `PAPER` (variant `paper`).

Plain dicts with units in the key names (m, rad, deg, s; `_frac` = share 0..1; `_n` = count). Per-class
values are dicts class -> value; a class missing from such a dict falls back to the `"*"` entry.
`resolve_params(params, variant)` merges a caller's (partial) dict over the variant's defaults and
rejects unknown keys, so a typo fails loudly. Every key is described in `DESCRIPTIONS`.
"""

from __future__ import annotations

import copy
import math

#: Variant `ours`: terrain-following seabed, BEV-correlation proposals, robust scene-to-model ICP
#: with two-way scoring, greedy explain-away selection and re-proposals from unexplained points.
DEFAULTS: dict = {
    "seed": 0,
    # Seabed.
    "ground_method": "grid",
    "ground_cell_m": 1.0,
    "ground_window_m": 7.0,
    "ground_refine_cell_m": 0.5,
    "ground_refine_bands_m": [0.3, 0.12],
    "ground_min_height_m": 0.15,
    "ransac_distance_m": 0.15,
    "ransac_iter_n": 1000,
    "ransac_sample_n": 20000,
    # Proposals (BEV height-map correlation).
    "bev_cell_m": 0.1,
    "bev_yaw_step_deg": 15.0,
    "proposal_ncc_min": 0.3,
    "proposal_occupancy_min_frac": 0.25,
    "proposal_nms_radius_frac": 0.4,
    "proposal_merge_m": 0.3,
    "proposal_vote_min_frac": 0.2,
    "proposal_max_rounds_n": 5,  # rounds stop earlier when one accepts nothing (3 before the dumped piles)
    "proposal_max_per_round_n": 1000,
    "proposal_min_points_frac": 0.15,
    "proposal_min_height_frac": 0.5,
    "proposal_data_min_frac": 0.3,
    "proposal_accepted_radius_frac": 0.5,
    "top_start_min_lift_m": 0.25,
    "coarse_probe_points_n": 150,
    "occluder_margin_m": 0.5,
    # Unexplained points: seeds of tumbled hypotheses.
    "residual_cluster_cell_m": 0.2,
    "residual_min_points_n": 40,
    "residual_min_height_m": 0.35,
    "residual_seed_sigma_m": 0.35,
    "residual_seed_sep_m": 0.6,
    "residual_max_seeds_n": 12,
    "residual_seed_cell_m": 0.1,
    "residual_seed_pad_m": 1.0,
    "residual_seed_min_density_frac": 0.25,
    "residual_centroid_sep_m": 0.3,
    "residual_height_seeds": True,
    "leftover_margin_m": 0.3,
    "leftover_claim_factor": 2.0,
    # Tumbled poses.
    "tumbled_inits": True,
    "tumbled_shift_q_min": 0.45,
    "tumbled_screen_keep_n": 4,
    "tumbled_tip_starts": True,
    "tumbled_vertex_stride_n": 5,
    "tumbled_azimuths_n": 8,
    "tumbled_stable_tilt_range_deg": [60.0, 150.0],
    "tumbled_stable_prob_min": 1e-3,
    "tumbled_tilt_round_deg": 5.0,
    "icp_screen_stage": [0.4, 6, 0.2],
    "icp_grid_cell_m": 0.03,
    "icp_grid_exact_coarse": True,
    # Registration.
    "crop_margin_m": 0.3,
    "icp_stages": [[0.35, 12, 0.15], [0.15, 8, 0.1]],
    "icp_tukey_k_frac": 0.5,
    "icp_min_points_n": 20,
    "surface_spacing_m": 0.06,
    "template_voxel_m": 0.05,
    "n_yaw_init": 2,
    "icp_xy_starts_m": 0.2,
    "icp_shift_q_range": [0.6, 0.95],
    "coarse_q_min": 0.3,
    "coarse_q_dist_m": 0.05,
    "coarse_n_min_frac": 0.5,
    "class_q_margin": 0.3,
    "class_competition_m": 0.6,
    # Scoring.
    "inlier_m": 0.05,
    # Objects unlike their models (chosen on dev and mismatch_dev, never test: README "Objects unlike
    # their models"): a third of a leg's radius thicker or thinner, and the height check above the
    # central 30 % of the box.
    "shape_tolerance_frac": 0.35,
    "overhang_max_frac": 0.5,
    "overhang_min_points_n": 5,
    "overhang_core_frac": 0.3,
    "coverage_m": 0.08,
    "coverage_voxel_m": 0.1,
    "claim_m": 0.08,
    "score_reach_margin_m": 0.15,
    "candidate_box_margin_m": 0.1,
    "coverage_z_band_m": 0.3,
    "coverage_asked_min_frac": 0.2,
    "hidden_footprint_margin_m": 0.05,
    "hidden_above_bottom_m": 0.1,
    # Crowds (dumped piles): unhit template points under observed ones are not asked for, chosen on dev,
    # mismatch_dev and the dumped-pile scenes of benchmarks/dumped_piles.py (README "Piles"), never test.
    "shadow_margin_m": 0.2,
    "shadow_cell_m": 0.15,
    "upright_tilt_max_deg": 30.0,
    "virtual_view_incidences_deg": [0.0, 30.0, 50.0],
    "virtual_view_azimuths_n": 4,
    "virtual_view_min_points_n": 10,
    "sink_vertex_stride_n": 7,
    "score_min": 0.15,
    "accept_min": 0.35,
    "new_min_frac": 0.5,
    "neighbour_support_overlap_max_frac": 0.2,
    "neighbour_support_f_t_min": 0.6,
    "replace_factor": 1.5,
    "penetration_max_frac": 0.05,
    "sink_max_m": 0.25,
    "rmse_max_m": {"*": 0.05},
    "keep_rejected": True,
    "rejected_score_factor": 0.1,
    # Selection (explain-away).
    "claim_crop_margin_m": 0.2,
    "penetration_surface_stride_n": 3,
    "replace_owner_min_frac": 0.2,
    "refit_lost_min_frac": 0.1,
    "refits_max_n": 2,
    "refit_inliers_lost_max_frac": 0.3,
    # Duplicates (of the non-accepted hypotheses kept for recall).
    "duplicate_dist_m": 0.5,
}

#: Variant `paper`: the source study's pipeline: one RANSAC plane, sliding windows per class, centroid
#: alignment + point-to-point ICP of one template, RMSE threshold per class, best of duplicates.
PAPER: dict = {
    "seed": 0,
    "ground_method": "ransac",
    "ground_cell_m": 1.0,
    "ground_window_m": 7.0,
    "ground_refine_cell_m": 0.5,
    "ground_refine_bands_m": [0.3, 0.12],
    # Above the seabed relief a single plane leaves (up to about 0.25 m on our scenes); the template
    # loses the same band, so the objects (0.75 m high and more) keep their shape.
    "ground_min_height_m": 0.3,
    "ransac_distance_m": 0.15,
    "ransac_iter_n": 1000,
    "ransac_sample_n": 20000,
    "window_scale": 1.3,
    # Window centres about 0.4 footprints apart: centroid alignment needs the object near the window
    # centre, and at 0.5 overlap the nearest window can be 0.33 footprints off in x and y.
    "window_overlap": 0.67,
    "window_min_points_frac": 0.25,
    "window_min_thickness_m": 0.03,
    "skip_empty_windows": True,
    "reuse_identical_windows": True,
    "window_max_n": 5000,
    "icp_max_corr_m": 0.3,
    "icp_max_iter": 30,
    "icp_refine_corr_m": 0.1,
    "icp_refine_iter": 20,
    "icp_backend": "compiled",
    "icp_min_points_n": 10,
    "template_view": "nadir",
    "surface_spacing_m": 0.06,
    "template_voxel_m": 0.12,
    "fitness_min": 0.6,
    # The study ranks detections by their RMSE; ranking by the tight template fitness is a step of the
    # improvement ladder (config model_based.ladder), not part of the study's pipeline.
    "score": "rmse",
    "score_corr_m": 0.1,
    # Calibrated on 10 training scenes: about the 99th percentile of the RMSE (at icp_max_corr_m) of
    # fits within 0.5 m of a true object of the class. Point-to-point RMSE includes the sampling gap
    # between two independent scans of one surface and the parts of neighbours within 0.3 m; the
    # threshold only rejects misfits, the tight fitness ranks.
    "rmse_max_m": {"reef_ring": 0.175, "reef_cone": 0.165, "tetrapod_b": 0.17, "tetrapod_s": 0.18, "*": 0.18},
    "duplicate_dist_m": 0.6,
    # 1.5 radii: short of the centre distance of two touching objects of different classes.
    "duplicate_other_class_frac": 1.5,
}

#: Key -> (unit, meaning); the final report and the config schema take their text from here.
DESCRIPTIONS: dict = {
    "seed": ("-", "seed of Open3D's RANSAC and Poisson-disk sampling (deterministic output)"),
    "ground_method": ("-", "'grid' (grid minimum + grey opening + median refinement) or 'ransac' (one plane)"),
    "ground_cell_m": ("m", "grid-minimum cell of the seabed DTM"),
    "ground_window_m": ("m", "grey-opening window; must bridge the widest object group's footprint"),
    "ground_refine_cell_m": ("m", "cell of the median refinement of the DTM"),
    "ground_refine_bands_m": ("m", "height bands around the current DTM whose points refine it, one pass each"),
    "ground_min_height_m": ("m", "points higher than this above the seabed are object candidates"),
    "ransac_distance_m": ("m", "inlier distance of the RANSAC seabed plane"),
    "ransac_iter_n": ("-", "RANSAC iterations for the seabed plane"),
    "ransac_sample_n": ("-", "points (seeded random subset) the RANSAC plane is fitted on"),
    "bev_cell_m": ("m", "cell of the height-above-seabed map and of the class kernels"),
    "bev_yaw_step_deg": ("deg", "yaw step of the kernels of n-fold symmetric classes (within one period)"),
    "proposal_ncc_min": ("-", "minimum masked normalised cross-correlation of a proposal peak"),
    "proposal_occupancy_min_frac": ("-", "minimum share of the kernel footprint holding points above the seabed"),
    "proposal_nms_radius_frac": ("-", "peak suppression radius as a share of the class radius"),
    "proposal_vote_min_frac": ("-",
                               'later rounds: minimum share of a class footprint occupied by unexplained points (vote '
                               'proposals)'),
    "proposal_merge_m": ("m", "proposals of one class closer than this are merged"),
    "proposal_min_points_frac": ("-", "skip proposals whose crop holds fewer candidate points than this share of "
                                      "the class's median template view (the 'skip empty windows' of ours)"),
    "proposal_min_height_frac": ("-", "skip proposals whose crop is lower above the seabed than this share of the "
                                      "class height (of the pose tried)"),
    "proposal_max_rounds_n": ("-", "proposal/accept rounds; later rounds use only unexplained points"),
    "proposal_max_per_round_n": ("-", "time bound on dense or pathological clouds: at most this many upright "
                                      "proposals (the best-correlating ones) and, separately, this many tumbled "
                                      "seed tries are fitted per round; the rest are dropped, counted in the "
                                      "statistics (capped) and logged. The default is above anything the default "
                                      "scenes need (at most 875 proposals in a whole scene), so it changes no "
                                      "result there"),
    "proposal_data_min_frac": ("-", "a cell's NCC counts only when at least this share of the kernel's support "
                                    "cells hold data (not sonar shadow, not hidden under an accepted object)"),
    "proposal_accepted_radius_frac": ("-", "proposals closer than this share of the class radius to an accepted "
                                           "object of the same class are skipped"),
    "top_start_min_lift_m": ("m", "a second, top-aligned start height is tried when the crop's highest point "
                                  "lies more than this above the top of the object resting on the seabed "
                                  "(it may rest on others); upright and tumbled starts"),
    "coarse_probe_points_n": ("-", "the coarse quality is measured on about this many crop points (every "
                                   "k-th point of the crop)"),
    "occluder_margin_m": ("m", "accepted objects whose box comes within class radius + this of a hypothesis' "
                               "position occlude it: template points hidden under them are not asked for"),
    "residual_cluster_cell_m": ("m", "BEV cell of the 8-connected clustering of unexplained points"),
    "residual_min_points_n": ("-", "unexplained clusters with fewer points are ignored"),
    "residual_min_height_m": ("m", "unexplained clusters lower than this above the seabed are ignored"),
    "residual_seed_sigma_m": ("m", "Gaussian smoothing of the unexplained-point density whose peaks seed "
                                   "tumbled hypotheses"),
    "residual_seed_sep_m": ("m", "least distance between two such seeds"),
    "residual_max_seeds_n": ("-", "most seeds per cluster of unexplained points"),
    "residual_seed_cell_m": ("m", "cell of the density raster of a cluster whose peaks are the seeds"),
    "residual_seed_pad_m": ("m", "margin of that raster around the cluster (the smoothing is not cut off)"),
    "residual_seed_min_density_frac": ("-", "density peaks lower than this share of the cluster's highest "
                                            "density seed nothing"),
    "residual_height_seeds": ("-", "also seed at the local maxima of the cluster's height above the seabed (one "
                                   "raised leg per element of a dumped pile, at every layer)"),
    "residual_centroid_sep_m": ("m", "the cluster's centroid is a seed too unless a density peak is this close"),
    "leftover_margin_m": ("m", "leftovers of an accepted object are looked for within its radius + this and its "
                               "box grown by this"),
    "leftover_claim_factor": ("-", "points within this x claim_m of an accepted object's mesh are its "
                                   "leftovers (feet, edges, noise) and seed no tumbled hypothesis"),
    "tumbled_inits": ("-",
                      'try tumbled orientations (cone on its side, ring on edge, tilted tetrapods) on '
                      'unexplained clusters'),
    "tumbled_shift_q_min": ("-", "tumbled starts: shifted restarts already from this coarse quality"),
    "tumbled_tip_starts": ("-", "at a height seed, tumbled starts with the pose's highest point under the seed at "
                                "the crop's top (a raised leg's tip of a leaning pile member), not centred on it"),
    "tumbled_screen_keep_n": ("-",
                              'tumbled starts: only the best this many after the screening ICP go on to the coarse '
                              'stage'),
    "tumbled_vertex_stride_n": ("-", "every n-th mesh vertex gives a tumbled pose's height and footprint "
                                     "centre (start position)"),
    "tumbled_azimuths_n": ("-", "classes tumbled by their stable poses (spec tumble mode 'stable_poses': rings, "
                                "cones): azimuths (evenly spread) per stable tilt"),
    "tumbled_stable_tilt_range_deg": ("deg", "those classes: stable resting poses (trimesh compute_stable_poses) "
                                             "tilted within [lo, hi] from upright are tried; upright and upside-down "
                                             "ones come from the upright start"),
    "tumbled_stable_prob_min": ("-", "those classes: stable poses less probable than this (trimesh's quasi-static "
                                     "drop probability) are left out"),
    "tumbled_tilt_round_deg": ("deg", "those classes: stable tilts are rounded to multiples of this, so near-equal "
                                      "poses are tried once"),
    "icp_screen_stage": ("m, -, m",
                         'screening ICP of many starts: [max correspondence distance, iterations, source voxel]'),
    "icp_grid_cell_m": ("m", "cell of the model surfaces' nearest-sample grids on which every ICP stage runs "
                             "all starts of a crop in one compiled call (0: Open3D, one call per start)"),
    "icp_grid_exact_coarse": ("-", "screening and coarse stages on the grid also refine each correspondence to "
                                   "the nearest sample (as the fine stages and the coarse quality always do): "
                                   "a correspondence then depends on the point, not on the cell it falls in, "
                                   "so tiled and whole runs agree (tests/test_tiling.py); false is faster"),
    "crop_margin_m": ("m", "scene crop radius = class radius + this"),
    "icp_stages": ("m, -, m",
                   'coarse-to-fine ICP: [max correspondence distance, iterations, source voxel] per stage'),
    "icp_tukey_k_frac": ("-", "Tukey kernel width as a share of the stage's correspondence distance"),
    "icp_min_points_n": ("-", "fewest points for a fit (ours: crop points and ICP correspondences; paper: "
                              "template and window points)"),
    "surface_spacing_m": ("m", "spacing of the mesh surface samples (ICP target)"),
    "template_voxel_m": ("m", "voxel that thins the registered template view (paper; ours does not use it)"),
    "icp_xy_starts_m": ("m", "shifted coarse restarts this far off the best start in +-x and +-y (0: off)"),
    "icp_shift_q_range": ("-",
                          'shifted restarts only when the best coarse quality (share of crop points within '
                          'coarse_q_dist_m) is in [lo, hi)'),
    "coarse_q_dist_m": ("m",
                        'distance to the model surface within which a crop point counts for the coarse quality'),
    "coarse_q_min": ("-", "proposals whose best coarse quality is lower are dropped, unless..."),
    "coarse_n_min_frac": ("-", "...their crop holds at least this share of the class's median template view "
                               "on the surface (crowded crops: piles)"),
    "class_q_margin": ("-",
                       'proposals more than this below the best coarse quality of any class within '
                       'class_competition_m are dropped'),
    "class_competition_m": ("m", "radius of the class competition between proposals"),
    "n_yaw_init": ("-", "yaw starts per proposal for n-fold symmetric classes (spread over one period)"),
    "inlier_m": ("m", "scene point to mesh distance counted as explained by a hypothesis"),
    "shape_tolerance_frac": ("-", "objects may be uniformly thicker or thinner than their model by this share of the "
                                  "class's half thickness (a leg's radius, half a wall): the median signed distance of "
                                  "the points near the surface, within that bound, is taken out before the inlier test "
                                  "and the RMSE (0: off)"),
    "overhang_max_frac": ("-", "gross height check: unexplained soundings above a hypothesis' box (within its "
                               "footprint) lower its score in proportion to how far they rise, reaching 0 at this "
                               "share of the box height: a 1.42 m class cannot label a 2.08 m object (0: off)"),
    "overhang_core_frac": ("-", "the height check looks above this central share of the box's length and width (1: "
                                "the whole footprint)"),
    "overhang_min_points_n": ("-", "the height of the soundings above a box is that of its n-th highest point (robust "
                                   "to single noise spikes)"),
    "coverage_m": ("m", "template point to scene distance counted as seen (template->scene fraction)"),
    "coverage_voxel_m": ("m", "voxel thinning the template views (and ray spacing of the virtual views of "
                               "tumbled poses) "
                               "for the template->scene fraction"),
    "claim_m": ("m", "scene points this close to an accepted object's mesh are explained by it"),
    "score_reach_margin_m": ("m", "candidate points of a hypothesis are searched within half its box "
                                  "diagonal + this of the box centre (xy)"),
    "candidate_box_margin_m": ("m", "candidate points of a hypothesis: inside its posed box grown by this"),
    "coverage_z_band_m": ("m", "scene points for the template->scene fraction lie within half the box height + "
                               "this of the box centre's height"),
    "coverage_asked_min_frac": ("-", "the template->scene fraction of a view is divided by at least this share "
                                     "of its points (a view mostly hidden under accepted objects cannot score "
                                     "high on its few visible points)"),
    "hidden_footprint_margin_m": ("m", "a template point is hidden under an accepted object when inside its "
                                       "footprint grown by this ..."),
    "hidden_above_bottom_m": ("m", "... and no higher than this above its bottom"),
    "shadow_margin_m": ("m", "a template point no scene point is near is not asked either when an observed "
                             "point lies more than this above it within a shadow_cell_m cell or the 8 "
                             "around (hidden by something seen, e.g. a neighbour in a pile; 0: off)"),
    "shadow_cell_m": ("m", "cell of the highest-observed-point map of the shadow test (shadow_margin_m)"),
    "upright_tilt_max_deg": ("deg", "poses tilted less than this from resting are upright: scored against the "
                                    "template views; others against virtual views of the posed mesh"),
    "virtual_view_incidences_deg": ("deg", "virtual views of tumbled poses: look directions off nadir "
                                           "(0: nadir)"),
    "virtual_view_azimuths_n": ("-", "virtual views: sides (evenly spread azimuths) each oblique direction "
                                     "looks from"),
    "virtual_view_min_points_n": ("-", "virtual views with fewer points are not used"),
    "sink_vertex_stride_n": ("-", "every n-th mesh vertex is tested against the seabed (sink_max_m)"),
    "score_min": ("-", "hypotheses scoring less are dropped"),
    "neighbour_support_overlap_max_frac": ("-", "pending hypotheses sharing at most this share of the smaller "
                                           "inlier set support each other: a neighbour's inliers in one's box do "
                                           "not lower its f_s (dumped piles; 0: off)"),
    "neighbour_support_f_t_min": ("-", "least f_t of a pending hypothesis that supports its neighbours so"),
    "accept_min": ("-", "score needed to accept a hypothesis as an object (explain-away)"),
    "new_min_frac": ("-", "share of a hypothesis' inliers not yet explained needed to accept it"),
    "replace_factor": ("-", "a hypothesis whose inliers are mostly explained already may replace the accepted "
                            "objects owning them if it scores this many times each of them (0: never)"),
    "penetration_max_frac": ("-", "largest share of a hypothesis' surface inside an accepted object"),
    "sink_max_m": ("m",
                   'a hypothesis whose lowest vertex is deeper than this below the seabed is implausible '
                   '(score 0)'),
    "rmse_max_m": ("m", "per class: largest inlier RMSE of an accepted fit"),
    "keep_rejected": ("-", "also output non-accepted hypotheses (score scaled down) for recall at low rank"),
    "rejected_score_factor": ("-", "score factor of non-accepted hypotheses"),
    "claim_crop_margin_m": ("m", "an accepted object claims points within class radius + this (and within "
                                 "claim_m of its mesh)"),
    "penetration_surface_stride_n": ("-", "every n-th surface sample is tested for penetration_max_frac"),
    "replace_owner_min_frac": ("-", "a hypothesis may replace the accepted objects owning at least this share "
                                    "of its inliers (replace_factor)"),
    "refit_lost_min_frac": ("-", "a pending hypothesis that lost more than this share of its candidate points to "
                                 "a newly accepted object is refitted on the rest (else re-scored)"),
    "refits_max_n": ("-", "most refits of one hypothesis"),
    "refit_inliers_lost_max_frac": ("-", "no refit (re-scored instead) when the newly accepted object took more than "
                                         "this share of the hypothesis' inliers (it explained the same object; 1: "
                                         "refit always)"),
    "window_scale": ("-", "window side = class footprint (largest horizontal extent) x this"),
    "window_overlap": ("-", "overlap of adjacent windows (0..1)"),
    "window_min_points_frac": ("-",
                               "skip windows with fewer object-candidate points than this share of the class's median "
                               'template view'),
    "window_min_thickness_m": ("m",
                               "windows whose points' smallest principal spread is below this are planar (seabed): not "
                               'registered'),
    "skip_empty_windows": ("-",
                           'skip windows below the point threshold (False: register every window, for benchmarks)'),
    "reuse_identical_windows": ("-",
                                "a window holding exactly the candidate points of an earlier window of its class "
                                "gets that window's fit instead of a second registration: the same detections at "
                                "less cost (False: register every window, for benchmarks)"),
    "window_max_n": ("-", "time bound on dense or pathological clouds: at most this many windows per class are "
                          "registered (those holding the most candidate points); the rest are dropped, counted in "
                          "the statistics (capped) and logged. The default is above anything the default scenes "
                          "need (at most 3163 registered windows in a whole scene)"),
    "icp_max_corr_m": ("m", "point-to-point ICP correspondence distance (paper)"),
    "icp_max_iter": ("-", "point-to-point ICP iterations (paper)"),
    "icp_refine_corr_m": ("m", "correspondence distance of the point-to-point ICP refinement that follows (paper)"),
    "icp_refine_iter": ("-", "iterations of that refinement (paper; 0: no refinement)"),
    "icp_backend": ("-", "paper: 'compiled' (Open3D's point-to-point ICP algorithm, compiled on one search grid "
                         "per window, sonardet.detect.model_based.window_icp) or 'open3d' (Open3D's "
                         "registration_icp; the same poses to rounding, slower)"),
    "template_view": ("-", "'nadir' (view under the track, yaw 0) or 'all' (every view tried, best RMSE)"),
    "fitness_min": ("-", "least share of template points with a correspondence (paper)"),
    "score": ("-", "paper ranking: 'rmse' (1 - rmse / rmse_max), 'fitness_rmse' (fitness x that) or "
                   "'tight_fitness' (share of template points within score_corr_m of a window point)"),
    "score_corr_m": ("m", "distance within which a posed template point counts as on the scan ('tight_fitness')"),
    "duplicate_dist_m": ("m", "detections with centres closer than this are duplicates; the best is kept (ours: any "
                               "class, among the non-accepted hypotheses kept for recall; paper: the same class)"),
    "duplicate_other_class_frac": ("-", "paper: a detection closer than this share of the radius of a better-scored "
                                        "detection of another class duplicates it (a part of that object)"),
}

VARIANTS = {"ours": DEFAULTS, "paper": PAPER}


def resolve_params(params: dict | None, variant: str) -> dict:
    """The variant's defaults updated with `params` (deep copy).

    Raises ValueError for an unknown variant, a key the variant does not have (unknown, or one of the
    other variant's), a non-finite number or a window overlap outside [0, 1).
    """
    if variant not in VARIANTS:
        raise ValueError(f"unknown model-based variant {variant!r}; choose one of {sorted(VARIANTS)}")
    base = VARIANTS[variant]
    out = copy.deepcopy(base)
    for k, v in (params or {}).items():
        if k not in base:
            other = [n for n, d in VARIANTS.items() if k in d]
            hint = f" (a parameter of variant {other[0]!r})" if other else ""
            raise ValueError(f"unknown model-based detector parameter {k!r} for variant {variant!r}{hint}; "
                             f"known: {', '.join(sorted(base))}")
        if isinstance(v, float) and not math.isfinite(v):
            raise ValueError(f"model-based detector parameter {k!r} must be finite, got {v!r}")
        out[k] = copy.deepcopy(v)
    if not 0.0 <= float(out.get("window_overlap", 0.5)) < 1.0:
        raise ValueError(f"window_overlap must be in [0, 1), got {out['window_overlap']}")
    if out.get("icp_backend", "compiled") not in ("compiled", "open3d"):
        raise ValueError(f"icp_backend must be 'compiled' or 'open3d', got {out['icp_backend']!r}")
    return out


def per_class(value, cls: str):
    """A per-class parameter's value for `cls` (dict with optional '*' fallback, or a scalar)."""
    if isinstance(value, dict):
        if cls in value:
            return value[cls]
        if "*" in value:
            return value["*"]
        raise ValueError(f"per-class parameter has no entry for {cls!r} and no '*' fallback: {value}")
    return value
