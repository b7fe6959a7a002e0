"""What every model's training shares: the fit loop and its checkpoints, data loading, spectral
errors, ONNX export, timing."""
