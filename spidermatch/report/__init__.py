"""What a run shows: colours, renders, PNGs, the HTML viewer and the dense map's files."""
