"""What a model is judged by: its evaluation on the runs, the residuals by regime against
their noise band, cross-validation on held-out folds, the criteria a candidate must
meet, and whether an effect's size is resolved by the data."""
