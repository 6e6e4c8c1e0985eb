"""Readers for recorded datasets (real drives) used by ``ins-hil replay``."""
