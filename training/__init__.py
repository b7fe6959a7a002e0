"""Training package: builds the benchmark data and trains the models that ``app`` serves.

It imports ``app.geometry`` so that training data and served requests share one spectrum
definition; ``app`` never imports this package.
"""
