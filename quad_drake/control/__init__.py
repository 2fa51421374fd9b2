"""Pure control laws: the FCND cascade controller (SPEC §5)."""
