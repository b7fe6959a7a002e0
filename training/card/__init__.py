"""The model card and the evaluation pages: tables rendered from metrics, before → after comparisons."""
