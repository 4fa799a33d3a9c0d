"""How much the test suite catches: deliberate errors, one at a time."""
