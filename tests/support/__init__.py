"""What the tests share: helpers (a simulated printer, distances), random G-code programs,
the mocked plugin, the real-server utilities, and the path of the sample files."""

import os

DATA = os.path.join(os.path.dirname(os.path.dirname(__file__)), "data")
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(__file__)))
