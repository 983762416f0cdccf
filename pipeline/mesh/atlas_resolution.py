"""The atlas's default size, apart from `atlas` (numpy, xatlas): the bake's options and the CLI's help
read it without importing the numerical stack."""

#: Atlas texels per side unless asked otherwise (the bake's ``atlas_resolution`` default).
RESOLUTION = 512
