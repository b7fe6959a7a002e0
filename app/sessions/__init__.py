"""A scanning session's logic, free of HTTP: its views' union solved once (``fused``)."""
