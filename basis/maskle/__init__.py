"""The Maskle: painted weights moved from a low-resolution mask onto any face mesh.

Evans et al., "The Maskle: automatic weighting for facial animation". See
:mod:`.mask` (asset), :mod:`.fitting` (placement and shrinking),
:mod:`.transfer` (rays, Shepard, smoothing), :mod:`.painting` (painting by
example), :mod:`.envelope` (baseline) and :mod:`.gold` (reference weights).
"""

from basis.maskle.envelope import Envelope, calibrate_envelope, envelope_weights
from basis.maskle.fitting import FIT_STATUSES, MaskFit, fit_mask, landmark_points
from basis.maskle.mask import (
                   CHANNEL_KINDS,
                   DEFAULT_MASK_PATH,
                   Mask,
                   load_default_mask,
                   load_mask,
                   save_mask,
)
from basis.maskle.painting import paint_mask
from basis.maskle.transfer import (
                   MaskleWeights,
                   TransferOperator,
                   maskle_weights,
                   shepard_coefficients,
                   smoothing_operator,
                   transfer_operator,
)

__all__ = ["Mask", "CHANNEL_KINDS", "DEFAULT_MASK_PATH", "load_mask", "save_mask",
           "load_default_mask", "MaskFit", "FIT_STATUSES", "fit_mask", "landmark_points",
           "TransferOperator", "MaskleWeights", "transfer_operator", "shepard_coefficients",
           "smoothing_operator", "maskle_weights", "paint_mask", "Envelope",
           "envelope_weights", "calibrate_envelope"]
