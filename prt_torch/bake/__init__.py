"""prt_torch.bake."""
