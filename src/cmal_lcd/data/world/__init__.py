"""data/world"""
