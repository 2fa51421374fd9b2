"""Where ``fleet/estimators.py`` finds ``declare_state_output``, which now lives in
``systems._io`` with the other port helpers: the fleet's sensor, plant, controller, trajectory,
fault and noise systems are the per-vehicle ones sized by ``n`` (issue 28). Goes when the
estimators are folded the same way."""

from quad_drake.systems._io import declare_state_output

__all__ = ["declare_state_output"]
