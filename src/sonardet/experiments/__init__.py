"""Experiments built on the methods registry: the speed-against-error ablation grid and the
one-at-a-time realism ablation."""
