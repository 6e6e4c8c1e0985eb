"""ins_hil.commands."""
