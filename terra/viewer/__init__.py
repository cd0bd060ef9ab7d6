"""`terra view`: the map and its scene graph in the browser (viser), with the task queries.

`scene` computes what is drawn (display subsets, colours, layers) as plain arrays; `app` wires
them into a viser server and its GUI. Every query goes through the typed task API on the one
LoadedBundle that `terra serve` also holds (terra.loaded), never through a second copy.
"""
