"""KinComp's version and home page, written once. The package root hands them on as
OctoPrint's ``__version__`` and ``__plugin_url__``; setuptools reads the version here."""

VERSION = "0.1.0"

# the project's homepage (its README); also the plugin repository entry's homepage and source
# (extras/kincomp.md) and the GitHub repository of releases (software update)
HOMEPAGE = "https://github.com/kincomp/OctoPrint-KinComp"
