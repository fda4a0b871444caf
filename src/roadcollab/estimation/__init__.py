"""Single-vehicle estimation: JDP estimator (Lemma 1), input observer (eq. 4), the DFT grid."""
