"""Many trials: the grid, the Ray scheduler, the MLflow tracking writer, the launch runner, progress, the lock."""
