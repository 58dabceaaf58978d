"""Shape collections with ground truth: FAUST_r-style folders and generated creatures."""
