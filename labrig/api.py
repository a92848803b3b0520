"""The public verbs under their first name: ``labrig.api`` is :mod:`labrig.verbs`."""
from labrig.verbs import *  # noqa: F401,F403
from labrig.verbs import __all__  # noqa: F401
