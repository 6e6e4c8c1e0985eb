"""ins_hil.fdi."""
