"""The diffusion profile models a material may be evaluated with, apart from `materials` and
`profile` (numpy): the bake's options and the CLI's ``--profile`` read them without the numerical
stack."""

#: Diffusion profile models (`profile.py`): the Monte Carlo-matched default and the classical dipole
#: of Jensen et al. 2001, kept to reproduce the papers.
PROFILE_MODELS = ("montecarlo", "dipole")
DEFAULT_PROFILE = "montecarlo"
