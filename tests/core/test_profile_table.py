"""The tabulated Rd matches the closed form to its tolerance, near the source and far off."""

import numpy as np

from sssbake.pipeline.core.profile import diffuse_reflectance_profile, profile_for
from sssbake.pipeline.core.materials import preset
from sssbake.pipeline.core.profile_table import TOLERANCE, ProfileTable


def test_table_matches_the_closed_form_everywhere():
    for name in ("marble", "skin1", "ketchup"):
        p = profile_for(preset(name))
        table = ProfileTable.build(p, 30.0, nodes=1 << 14)
        d = np.r_[0.0, np.geomspace(1e-4, 40.0, 5000)]  # beyond 30 mm: the closed form
        exact = diffuse_reflectance_profile(d, p)
        np.testing.assert_allclose(table(d * d), exact, rtol=2 * TOLERANCE, err_msg=name)
        assert table.exact_below > 0  # the coarse grid needs the closed form near the source
