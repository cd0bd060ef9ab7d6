"""Interoperability: a bundle out to the formats other tools read, and the authors' map files in.

One module per format: `spark` (spark_dsg JSON for Hydra and Clio users), `node_link` (networkx
node-link JSON), `ply` (the map's points, coloured), `reference_export` / `reference_import` (the
metric-semantic map files of the authors' Phase 1, ../shared/reference-notes.md section 1) with
`reference_files` reading theirs safely. `export.export_bundle` dispatches by format name.
"""
