"""What a user runs beside the node: registering and verifying files, replaying a recording, a
batch of pairs, the clients that ask a running node, and the preset files' writer."""
