"""The learned union operator (torch): its configuration, network, training, calibration, evaluation and export."""
