"""Image metrics (DESIGN §3): the core's one implementation, cross-checked against scikit-image.

Inputs are :class:`lumigraph.Frame` objects or numpy arrays: colour images (H, W, 3|4) uint8
(alpha is ignored), coverage masks (H, W) bool, depth images (H, W) float (+inf = no hit).

- :func:`psnr`: PSNR (dB) on R, G, B, data range 255, over the frame or a mask;
- :func:`masked_psnr`: PSNR over the union of both coverage masks (the harsher number used for
  every quality target);
- :func:`ssim`: mean SSIM as ``skimage.metrics.structural_similarity(channel_axis=-1,
  data_range=255)``;
- :func:`mae`: mean absolute difference per component, in 8-bit steps;
- :func:`depth_error`: absolute depth error statistics over the intersection of the masks;
- :func:`compare`: all of the above for two frames, as ``lumigraph eval`` reports them.
"""

from ._lumigraph import compare, depth_error, mae, masked_psnr, psnr, ssim

__all__ = ["compare", "depth_error", "mae", "masked_psnr", "psnr", "ssim"]
