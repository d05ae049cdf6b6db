"""insitu-soil tests: one package per project package, plus graph/ and workspace/."""
