"""The correspondence model: each vertex of a part → its place on the template.

Data (parts), network, training, export and evaluation."""
