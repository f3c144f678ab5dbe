"""prt_torch.brdf."""
