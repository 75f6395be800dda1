"""The agent core as layers (:mod:`onboard.core.agent`): configuration groups, the peer table,
the layer protocol, and the layers of paper 000 and paper 003 a mode composes."""
