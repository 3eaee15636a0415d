# Detection on survey files (config `surveys`), one job per tile, so a large survey scales
# out on a cluster and a job's memory is bounded by its tile:
#   checkpoint survey_tiles   survey file -> tiles/{tile}.npz (padded tile points) + tile_index.json
#   detect_survey_tile        one tile's points -> its detections (survey coordinates)
#   survey_detections         merge of the tiles (each object once, by the tile owning its centre)
#                             -> detections.{json,csv,geojson}, detections_crs.geojson, the classified
#                             soundings (soundings.laz) and the posed meshes (objects.ply), in the
#                             survey's coordinates/CRS (sonardet.survey.outputs, as `sonardet detect`)
# The tiles to detect are known only once the survey is read: survey_detections asks the checkpoint's
# tile index for them. Library: sonardet.survey (split, merge, tiling, settings).
wildcard_constraints:
    survey="|".join(SURVEYS) or "(?!)",
    tile=r"t[0-9]+_[0-9]+",


checkpoint survey_tiles:
    input:
        survey=lambda w: SURVEYS[w.survey]["path"],
        # The object meshes give the largest footprint, the smallest overlap that keeps seams exact.
        meshes=object_files("ply"),
        meta=object_files("json"),
    output:
        tiles=directory("results/surveys/{survey}/tiles"),
        index="results/surveys/{survey}/tile_index.json",
    log:
        "results/logs/survey_tiles/{survey}.log",
    benchmark:
        "results/benchmarks/survey_tiles/{survey}.tsv"
    priority: PRIORITY["survey"]
    conda:
        "../environment.yml"
    threads: 1
    resources:
        mem_mb=MEM_MB["survey"],
        runtime=RUNTIME_MIN["survey"],
    params:
        split=lambda w: {
            k: SURVEYS[w.survey][k]
            for k in (
                "crs",
                "z_positive",
                "columns",
                "tile_m",
                "overlap_m",
                "chunk_points",
                "keep_fliers",
            )
        },
    script:
        "../workflow_scripts/survey_tiles.py"


rule detect_survey_tile:
    input:
        unpack(survey_tile_inputs),
    output:
        detections="results/surveys/{survey}/tile_detections/{tile}.json",
        stats="results/surveys/{survey}/tile_stats/{tile}.json",
    log:
        "results/logs/detect_survey_tile/{survey}/{tile}.log",
    benchmark:
        "results/benchmarks/detect_survey_tile/{survey}/{tile}.tsv"
    priority: PRIORITY["survey"]
    conda:
        "../environment.yml"
    threads: lambda w: SURVEY_METHOD[w.survey].threads
    resources:
        mem_mb=MEM_MB["survey"],
        runtime=RUNTIME_MIN["survey"],
    params:
        method=lambda w: SURVEY_METHOD[w.survey].to_dict(),
        classes=CLASSES,
    script:
        "../workflow_scripts/detect_survey_tile.py"


rule survey_detections:
    input:
        survey=lambda w: SURVEYS[w.survey]["path"],
        meshes=object_files("ply"),
        meta=object_files("json"),
        index="results/surveys/{survey}/tile_index.json",
        detections=lambda w: expand(
            "results/surveys/{survey}/tile_detections/{tile}.json",
            survey=w.survey,
            tile=tile_ids(checkpoints.survey_tiles.get(survey=w.survey).output.index),
        ),
        stats=lambda w: expand(
            "results/surveys/{survey}/tile_stats/{tile}.json",
            survey=w.survey,
            tile=tile_ids(checkpoints.survey_tiles.get(survey=w.survey).output.index),
        ),
    output:
        json="results/surveys/{survey}/detections.json",
        csv="results/surveys/{survey}/detections.csv",
        csv_meta="results/surveys/{survey}/detections.csv.json",
        geojson="results/surveys/{survey}/detections.geojson",
        geojson_crs="results/surveys/{survey}/detections_crs.geojson",
        las="results/surveys/{survey}/soundings.laz",
        objects="results/surveys/{survey}/objects.ply",
        summary="results/surveys/{survey}/summary.json",
    log:
        "results/logs/survey_detections/{survey}.log",
    benchmark:
        "results/benchmarks/survey_detections/{survey}.tsv"
    priority: PRIORITY["survey"]
    conda:
        "../environment.yml"
    threads: 1
    resources:
        mem_mb=MEM_MB["survey"],
        runtime=RUNTIME_MIN["survey"],
    params:
        method=lambda w: SURVEY_METHOD[w.survey].name,
        all_hypotheses=lambda w: SURVEYS[w.survey]["all_hypotheses"],
        source=lambda w: SURVEYS[w.survey]["path"],
        read=lambda w: {
            k: SURVEYS[w.survey][k]
            for k in ("crs", "z_positive", "columns", "chunk_points")
        },
        classes=CLASSES,
    script:
        "../workflow_scripts/survey_detections.py"
