"""Scanning sessions on anny bodies: what the sessions' σ is calibrated and scored on."""
