"""prt_torch.rig: skinned characters (skeleton, LBS, pose features, glTF/BVH loading, built-in humanoid).

Importing this package does not import torch (torch LBS lives in :mod:`prt_torch.rig.skinning_torch`).
"""

from prt_torch.rig.bvh import BvhSkeleton, load_bvh
from prt_torch.rig.character import Character, Poses
from prt_torch.rig.clip import Clip
from prt_torch.rig.features import pose_features
from prt_torch.rig.gltf import load_gltf
from prt_torch.rig.random_pose import random_poses
from prt_torch.rig.skeleton import forward_kinematics
from prt_torch.rig.skinning import skin

__all__ = ["BvhSkeleton", "Character", "Clip", "Poses", "forward_kinematics", "load_bvh", "load_gltf",
           "pose_features", "random_poses", "skin"]
