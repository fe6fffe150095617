"""Damaged video files for the tests that check a broken demonstrator video is named, in training and evaluation."""

from __future__ import annotations

from pathlib import Path


def overwrite_middle(video: Path) -> None:
    """Overwrite 1000 bytes in the middle of ``video``: the decoder fails part-way (a damaged copy)."""
    data = bytearray(video.read_bytes())
    middle = len(data) // 2
    data[middle : middle + 1000] = bytes(range(256)) * 3 + bytes(232)
    video.write_bytes(bytes(data))


def drop_last_frames(video: Path, dropped: int) -> None:
    """Re-encode ``video`` without its last ``dropped`` frames: it decodes cleanly, just short (a cut copy)."""
    import av

    with av.open(str(video)) as source:
        frames = [frame.to_ndarray(format="rgb24") for frame in source.decode(video=0)]
        rate = source.streams.video[0].average_rate
    shorter = video.with_suffix(".short.mp4")
    with av.open(str(shorter), "w") as target:
        stream = target.add_stream("mpeg4", rate=rate)
        stream.height, stream.width = frames[0].shape[:2]
        stream.pix_fmt = "yuv420p"
        for number, image in enumerate(frames[: len(frames) - dropped]):
            frame = av.VideoFrame.from_ndarray(image, format="rgb24")
            frame.pts = number
            target.mux(stream.encode(frame))
        target.mux(stream.encode())
    shorter.replace(video)
