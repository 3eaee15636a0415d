"""Characterise the noise of a real survey on flat patches and of the simulated sensor on a flat seabed."""

from common import job

import json

from sonardet.eval.noise import characterize_noise, simulated_flat_patch, to_json
from sonardet.io.atomic import atomic_outputs, atomic_write_text
from sonardet.io.points import read_points
from sonardet.report import plot_noise
from sonardet.seeds import derive_seed

with job(snakemake, "noise_characterization") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    cfg = smk.params.noise
    cloud = read_points(smk.input.survey)
    log.info("%s: %d points", smk.input.survey, len(cloud.xyz))
    real = []
    for patch in cfg["patches"]:
        res = characterize_noise(cloud.xyz, patch, z_trim=cfg["z_trim"], seed=int(smk.params.seed) % 2**31,
                                 name=patch["name"])
        real.append(res)
        log.info("%s: n %d, slope %.2f deg, sigma %.2f mm before, %.2f mm after trimming, robust %.2f mm, "
                 "skewness p %.3g before, %.3g after", patch["name"], res["n_points"], res["plane"]["slope_deg"],
                 1e3 * res["before"]["std_m"], 1e3 * res["after"]["std_m"], 1e3 * res["before"]["robust_sigma_m"],
                 res["before"]["skewtest_pvalue"], res["after"]["skewtest_pvalue"])
    sigma = float(smk.params.sensor["range_sigma_m"])
    sim_xyz = simulated_flat_patch(sigma, seed=derive_seed(smk.params.seed, "noise") % 2**31, sensor=dict(smk.params.sensor))
    # Near nadir only, like the real patches' footprint: off-nadir beams show only sigma * cos(angle).
    sim = characterize_noise(sim_xyz, {"x": [1.0, 9.0], "y": [-1.0, 1.0]}, z_trim=cfg["z_trim"], name="simulated")
    log.info("simulated (range sigma %.1f mm): sigma %.2f mm before, %.2f mm after trimming", 1e3 * sigma,
             1e3 * sim["before"]["std_m"], 1e3 * sim["after"]["std_m"])
    doc = {"survey": str(smk.input.survey), "crs": cfg["crs"], "z_trim": cfg["z_trim"],
           "real": [to_json(r) for r in real], "simulated": to_json(sim), "simulated_range_sigma_m": sigma}
    with atomic_outputs([smk.output.figure, smk.output.json]) as (figure, json_path):  # both or neither
        plot_noise(real[0], figure, simulated=sim)
        atomic_write_text(json_path, json.dumps(doc, indent=1) + "\n")
