"""robot_models"""
