"""Code shared by every cinetransfer service: messages, codec, keys, lens model, node runtime."""
