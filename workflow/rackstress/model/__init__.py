"""The paper's model as data: particle groups and racks, operators, scenes, and the stability prediction."""
