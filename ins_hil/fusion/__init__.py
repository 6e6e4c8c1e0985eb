"""ins_hil.fusion."""
