"""The FROST model: PCA dictionary (model, training), cell selection (SOMP), reconstruction, metrics."""
