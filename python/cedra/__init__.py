"""cedra: dynamics of the CEDRA six-wheel rescue rover (Kane's method in CasADi) shipped as an FMI 2.0 CS FMU."""
__version__ = "0.1.0"
