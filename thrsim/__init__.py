"""thrsim: physically-based and learned simulation of acetabular reaming."""

__version__ = "0.5.4"


def __getattr__(name: str):
    # the learned simulator pulls in PyTorch: imported only when asked for
    if name == "ReamingSimulator":
        from thrsim.learn.simulator import ReamingSimulator

        return ReamingSimulator
    raise AttributeError(f"module 'thrsim' has no attribute {name!r}")
