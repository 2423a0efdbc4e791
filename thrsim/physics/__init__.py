"""Material law, tet kinematics, contact, the explicit solver and the reaming case.

Every kernel here is cached by Numba in the user's cache folder, in a subfolder keyed on these
files and every thrsim module they import (:func:`thrsim.cache.use_numba_cache`).
"""

from thrsim.cache import use_numba_cache

use_numba_cache()
