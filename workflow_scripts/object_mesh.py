"""Build the mesh of one class and write it with its metadata."""

from common import job

from sonardet.objects import build_object, write_object

with job(snakemake, "object_mesh") as log:  # noqa: F821
    cls = snakemake.wildcards.cls  # noqa: F821
    objects = snakemake.params.objects  # noqa: F821
    model = build_object(cls, objects)
    meta = write_object(model, objects["density_kg_m3"], snakemake.output.ply, snakemake.output.json)  # noqa: F821
    log.info("%s: %d faces, height %.3f m, volume %.4f m^3 (spec %.4f), mass %.0f kg", cls, meta["n_faces"],
             meta["height_m"], meta["volume_m3"], meta["spec_volume_m3"], meta["mass_kg"])
