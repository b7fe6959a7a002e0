"""The learned models: union operator and region localizer (torch), their training and export."""
