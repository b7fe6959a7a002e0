"""What the service does with spectra: the ONNX union operator and localizer, and the template."""
