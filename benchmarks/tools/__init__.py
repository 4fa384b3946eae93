"""Tools for developers of driveopt, not measurements of it: where the test suite's compile time goes. README.md lists
them."""
