"""prt_torch.models."""
