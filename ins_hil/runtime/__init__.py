"""ins_hil.runtime."""
