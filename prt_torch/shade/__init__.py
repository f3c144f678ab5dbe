"""prt_torch.shade."""
