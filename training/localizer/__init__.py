"""The region localizer: which template vertices a part covers, from its spectrum (torch), and its training."""
