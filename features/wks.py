"""Wave Kernel Signature, re-exported from :mod:`spidermatch.geometry.descriptors` (pure numpy)."""

from spidermatch.geometry.descriptors import WKSExtractor, normalise_rows, wave_kernel_signature

__all__ = ["WKSExtractor", "normalise_rows", "wave_kernel_signature"]
