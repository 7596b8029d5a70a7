"""Experiments: MLflow tracking of runs, prerequisites through the model registry, and the report."""
