"""Drake LeafSystems: thin glue over the pure modules (the only place LeafSystems live)."""
