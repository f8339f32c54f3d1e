"""Work-precision and stability reports, the defaults report and the benchmark."""
