"""Densification: a map for every full-resolution source vertex from the certified sparse map."""
