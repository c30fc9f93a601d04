//! fdmlab-pipeline: spec schema, stage graph, content-addressed store, runs, export.
