"""Communication fault injection on real Zenoh traffic between real processes."""
