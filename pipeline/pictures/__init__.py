"""Pictures a person looks at: the input, the stress layout, the 3-D preview and the tool paths
(``render``, ``hfimage``), the screen-print texture, and the rasteriser and shading they share."""
