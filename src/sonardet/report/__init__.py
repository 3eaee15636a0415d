"""Report tables and figures: pure functions of result files (metrics, detections, stats, benchmarks)."""

from .figures import (
    image_is_informative,
    pareto_front,
    plot_3d_poses,
    plot_dataset_example,
    plot_loss_curves,
    plot_noise,
    plot_pareto,
    plot_pr_curves,
    plot_topview,
)
from .inputs import benchmark_summary, count_annotations, read_benchmark, read_metrics, read_pr_curves
from .scene_figures import densest_region, detection_list, place_mesh
from .summary import machine_info, write_results_readme
from .tables import (
    STUDY,
    comparison_table,
    dataset_table,
    domain_randomisation_table,
    fraction_table,
    latex_table,
    markdown_table,
    realism_ablation_table,
    timing_table,
    write_table,
)

__all__ = [
    "STUDY",
    "benchmark_summary",
    "comparison_table",
    "count_annotations",
    "dataset_table",
    "domain_randomisation_table",
    "densest_region",
    "detection_list",
    "fraction_table",
    "image_is_informative",
    "latex_table",
    "machine_info",
    "markdown_table",
    "pareto_front",
    "place_mesh",
    "plot_3d_poses",
    "plot_dataset_example",
    "plot_loss_curves",
    "plot_noise",
    "plot_pareto",
    "plot_pr_curves",
    "plot_topview",
    "read_benchmark",
    "read_metrics",
    "read_pr_curves",
    "realism_ablation_table",
    "timing_table",
    "write_results_readme",
    "write_table",
]
