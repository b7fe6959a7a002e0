"""Geometry: parse uploads, validate them, and compute their truncated Laplace–Beltrami spectra.

Nothing here knows about HTTP, torch or anny, so the service, the CLI and the training
package all compute spectra through this one code path.
"""
