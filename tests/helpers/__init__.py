"""Constants and plain functions the tests share, imported as ``from tests.helpers.<module> import ...``.

The conftest.py files hold only fixtures: several conftest.py files share the module name ``conftest``, so importing
from one by name is ambiguous once a pytest run spans more than one test folder.
"""
