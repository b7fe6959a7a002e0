"""A scanning session's logic, free of HTTP: the views kept whole (``session``, ``records``,
``store``, ``postgres``), their union read from all of them (``reading``): fused where they share
a frame (``fused``), aligned through their places first where they do not (``aligned``), or the
learned chain (``chain``), with σ from the sessions' calibration (``calibration``)."""
