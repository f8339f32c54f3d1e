"""From a model (cedra.contract.ModelSpec) to a checked FMU: variables, C code generation, packaging, checkers,
the sanitizer fuzzer."""
