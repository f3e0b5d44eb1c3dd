"""Reading real footage: image folders, video files and ROS bags behind one interface, with what a
real recording brings along: interlacing, repeated and dropped frames, and damage."""

from pipemap.footage.deinterlace import AUTO_METHOD as DEINTERLACE_AUTO
from pipemap.footage.deinterlace import METHODS as DEINTERLACE_METHODS
from pipemap.footage.deinterlace import SAMPLES as DEINTERLACE_SAMPLES
from pipemap.footage.deinterlace import deinterlace, interlaced
from pipemap.footage.images import ImageFolder, read_grey, read_mask, read_timestamps, to_grey
from pipemap.footage.records import Damage, FootageLog
from pipemap.footage.rosbag import RosBag, is_bag
from pipemap.footage.source import FrameSource, RawFrame
from pipemap.footage.stalls import RepeatDetector, frame_period, missing_before
from pipemap.footage.video import VideoFile

__all__ = ["DEINTERLACE_AUTO", "DEINTERLACE_METHODS", "DEINTERLACE_SAMPLES", "Damage", "FootageLog", "FrameSource",
           "ImageFolder", "RawFrame", "RepeatDetector", "RosBag", "VideoFile", "deinterlace", "frame_period",
           "interlaced", "is_bag", "missing_before", "read_grey", "read_mask", "read_timestamps", "to_grey"]
