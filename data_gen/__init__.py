"""data_gen: procedurally rendered synthetic stereo pairs with exact ground truth."""
