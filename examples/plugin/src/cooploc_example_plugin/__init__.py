"""An example cooploc plug-in: the `huber-kf` estimator and the `motorway` scenario family.

cooploc finds both through the entry points of this package (see its pyproject.toml):
`huber_kf.HuberKF` in the group ``cooploc.estimators`` and the module `motorway`, which
registers its presets when imported, in the group ``cooploc.scenarios``. Nothing is
imported here, so that loading one entry point does not load the other.
"""

__version__ = "0.1.0"
