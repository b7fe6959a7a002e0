"""The deformable-human benchmark data built from the ``anny`` body model."""
