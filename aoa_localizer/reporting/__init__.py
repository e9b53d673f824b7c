"""Reports for the map: plots, KML and GeoJSON export, and the report program."""
