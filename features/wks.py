"""Wave Kernel Signature: defined in :mod:`spidermatch.descriptors` (pure numpy), re-exported here."""

from spidermatch.descriptors import WKSExtractor, normalise_rows, wave_kernel_signature

__all__ = ["WKSExtractor", "normalise_rows", "wave_kernel_signature"]
