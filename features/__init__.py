"""Per-vertex shape descriptors: WKS (numpy) and a learned DiffusionNet (PyTorch, imported lazily)."""
