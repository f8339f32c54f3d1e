"""cedra: dynamics of the CEDRA six-wheel rescue rover (Kane's method in CasADi) shipped as an FMI 2.0 CS FMU."""
__version__ = "0.10.0"   # = pyproject.toml's (tests/test_docs.py); CHANGELOG.md: what each version brought
