"""The course's helper modules a student directory may lack (occupancy_map, graph_search), mounted behind
it as `proj1_3.code` and on sys.path for flat imports by groundstation.usercode.loader."""
