"""ompn_ros: Ordered Memory Policy Network (Lu et al., ICLR 2021) for online subtask segmentation."""

__version__ = "0.1.0"
