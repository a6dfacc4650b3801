"""Effects a scene may enable (BRIEF 3.1). Each is off unless asked for; the receiver
pipeline is assembled once per scene from the enabled ones, so a disabled effect draws
no random numbers, allocates nothing and adds no per-epoch branch."""

from .noise import NoiseEffect

__all__ = ["NoiseEffect"]
