"""Data sources behind one protocol (`base.Drive`): KITTI raw layout, and the synthetic world."""
