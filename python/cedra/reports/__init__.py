"""Work-precision and stability reports (issue 5)."""
