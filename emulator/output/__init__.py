"""Output: streams of sentences, the epoch scheduler, link faults and the ports that carry
the bytes (stdout, pty, serial, file, memory)."""
