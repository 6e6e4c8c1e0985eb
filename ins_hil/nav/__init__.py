"""Pure navigation math (no I/O): rotations, Earth model, mechanization and the book's algorithms."""
