"""State estimation: from noisy motion capture and rotor speeds to smooth states and derivatives."""
